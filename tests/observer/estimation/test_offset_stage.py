"""The armature voltage's offset measured per window (stages.offset_stage): its move as the
window measures it, in place of the prior's, in the std of a converter-fed armature."""

from __future__ import annotations

import numpy as np
import pytest

import observer.estimation.armature as armature
import observer.estimation.stages as stages
from observer.estimation import estimate_armature
from observer.estimation.motor import P12
from observer.simulation.converter import PRESETS
from observer.simulation.simulate import simulate

FS = 2000.0


@pytest.fixture(scope="module")
def moving_window():
    """The window from 10 s to 11 s of a 2 kHz realistic P-12 (seed 1): the drive moves
    (speed std ~30 rad/s, current std ~2 A), so the window tells an offset from ``Ra*ia``
    and ``K*if*w``."""
    rec = simulate(
        P12, duration_s=12.0, sample_rate_hz=FS, seed=1, drive=PRESETS["realistic"],
        drive_name="realistic",
    )  # fmt: skip
    t = np.asarray(rec.t)
    s = (t >= 10.0) & (t < 11.0)
    window = tuple(np.asarray(rec[c])[s] for c in ("va", "ia", "if", "omega"))
    assert window[3].std() > 20.0
    return window


@pytest.fixture(autouse=True)
def _offset_alone(monkeypatch):
    """The offset's own part of the std: the EMF's timing (stages.speed_delay), measured
    along its own direction, takes up some of an offset's misfit too."""
    monkeypatch.setattr(stages, "speed_delay", lambda problem, fit: None)


def _ra(window, offset_v: float = 0.0):
    va, ia, i_f, w = window
    est = estimate_armature(va + offset_v, ia, i_f, w, 1.0 / FS, rng=0)
    assert est.intersample == "smooth"  # a converter's measured voltage
    return est.resistance_ohm, est.std["R"]


@pytest.mark.slow
def test_a_window_that_tells_the_offset_apart_carries_less_than_the_prior(
    moving_window, monkeypatch
):
    value, std = _ra(moving_window)
    monkeypatch.setattr(armature, "offset_stage", lambda problem, fit: None)
    value_prior, std_prior = _ra(moving_window)
    assert value == pytest.approx(value_prior, rel=1e-12)  # carried, not corrected
    assert std < 0.95 * std_prior
    assert abs(value / P12.armature_resistance_ohm - 1.0) < 2.5 * std / value


def test_an_offset_beyond_the_prior_widens_the_std_to_cover_it(moving_window, monkeypatch):
    """0.5 V on the voltage sensor (0.23 % of the P-12's rated voltage, about three times the
    prior): Ra reads ~2.8 % high, at 2.8 std of the prior's std, within it with the offset
    measured."""
    truth = P12.armature_resistance_ohm
    value, std = _ra(moving_window, 0.5)
    monkeypatch.setattr(armature, "offset_stage", lambda problem, fit: None)
    value_prior, std_prior = _ra(moving_window, 0.5)
    assert value == pytest.approx(value_prior, rel=1e-12)
    assert abs(value_prior - truth) > 2.5 * std_prior
    assert abs(value - truth) < 2.5 * std
