"""The diagnosis's stages run alone: baseline, noise floor, locate, candidates, selection, verdict.

A short recording with one effect (a brush drop) and its clean twin; the full
pipeline on many cases is tested in test_diagnose.py.
"""

from __future__ import annotations

import pytest

from observer.diagnosis.diagnose import (
    HoldoutScorer,
    decide_verdict,
    fit_baseline,
    fit_candidates,
    locate_mismatch,
    noise_floors,
    select_effects,
)
from observer.diagnosis.fitting import split_segments
from observer.diagnosis.results import NONE
from observer.estimation.motor import P12
from observer.simulation.simulate import simulate

NAMES = ["brush_drop", "sensor_offset", "thermal_drift"]
SWARM = dict(n_particles=24, iterations=40, seed=0)


class _Bar:
    def update(self, n: int = 1) -> None: ...

    def set_description(self, text: str) -> None: ...


def _first_stages(effects):
    rec = simulate(P12, duration_s=6.0, sample_rate_hz=2000.0, seed=1, effects=effects)
    baseline = fit_baseline(rec, n_particles=60, iterations=60, seed=0)
    floors = noise_floors(baseline)
    return rec, baseline, floors, locate_mismatch(rec, baseline, floors)


def _last_stages(rec, baseline, floors, located):
    segments = split_segments(baseline.data.n, rec.dt, 24000)
    cands = fit_candidates(
        baseline, floors, NAMES, segments, compensate_input_noise=True, bar=_Bar(), **SWARM
    )
    scorer = HoldoutScorer(baseline.data, cands, floors)
    selection = select_effects(
        cands, scorer, NAMES, baseline.context, combine=3, bar=_Bar(), **SWARM
    )
    verdict = decide_verdict(rec, baseline, floors, located, cands, selection, NAMES, **SWARM)
    return cands, selection, verdict


@pytest.fixture(scope="module")
def brush():
    return _first_stages({"brush_drop": 0.3})


@pytest.fixture(scope="module")
def clean():
    return _first_stages(None)


def test_the_floor_explains_a_correct_models_residual(clean):
    _, baseline, floors, located = clean
    assert set(baseline.residuals) == {"field", "armature"}
    for floor in floors.values():
        assert 0.9 < floor.excess_ratio < 1.1
    assert not located.structure and not located.mismatch


def test_a_brush_drop_is_located_against_the_current_direction(brush):
    _, _, floors, located = brush
    assert floors["armature"].excess_ratio > 1.1
    strongest = located.structure[0]
    assert (strongest.channel, strongest.condition) == ("ia", "sign(ia)")


def test_candidates_are_scored_on_held_out_data_and_the_effect_selected(brush):
    cands, selection, verdict = _last_stages(*brush)
    assert set(cands.fits) == {NONE, *NAMES, *selection.pairs}
    assert selection.accepted_singles[0] == "brush_drop"
    assert selection.verdict == verdict.verdict == "brush_drop"
    assert verdict.findings[0].effect == "brush_drop" and verdict.findings[0].accepted


def test_nothing_is_selected_on_a_clean_recording(clean):
    _, selection, verdict = _last_stages(*clean)
    assert selection.verdict == verdict.verdict == NONE
    assert not selection.accepted_singles and not selection.pairs
