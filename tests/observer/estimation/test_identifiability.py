"""observer.estimation.identifiability: which parameters an estimate identifies."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from observer.config import QualityConfig
from observer.estimation import CircuitEstimate, SearchRange, identify
from observer.estimation.pso import PSOResult

LIMITS = QualityConfig().limits("armature")
FIELD_LIMITS = QualityConfig().limits("field")


def _estimate(circuit: str = "armature", **changes: object) -> CircuitEstimate:
    pso = PSOResult(np.zeros(2), 0.0, 1, 1, np.zeros(2), False, "")
    base = CircuitEstimate(
        circuit=circuit, resistance_ohm=3.5, inductance_h=0.02,
        emf_constant_h=1.12 if circuit == "armature" else None, initial_current_a=0.0,
        rms_a=0.01, std={"R": 0.001, "L": 0.0002, "K": 0.0001} if circuit == "armature"
        else {"R": 0.01, "L": 0.00005}, n_samples=1000,
        search_range=SearchRange((1.0, 10.0), (1e-3, 1.0)), pso=pso,
    )  # fmt: skip
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


def test_a_well_determined_estimate_is_identified():
    ident = identify(_estimate(), LIMITS)
    assert ident.quality() == {"R": "ok", "L": "ok", "K": "ok"}
    assert ident.unidentified == () and not ident.reasons


def test_a_large_relative_std_is_not_identified_and_says_why():
    ident = identify(_estimate(std={"R": 0.001, "L": 0.5, "K": 0.0001}), LIMITS)
    assert ident.quality() == {"R": "ok", "L": "none", "K": "ok"}
    assert "relative std" in ident.reasons["L"] and "> 2 %" in ident.reasons["L"]


def test_an_estimate_whose_model_does_not_describe_the_window_is_no_evidence():
    """describes_window=False: nothing is identified, however small the std."""
    est = _estimate(describes_window=False, note="voltage between samples unknown")
    ident = identify(est, LIMITS)
    assert ident.quality() == {"R": "none", "L": "none", "K": "none"}
    assert "voltage between samples unknown" in ident.reasons["R"]


def test_armature_r_and_k_are_identified_together():
    ident = identify(_estimate(std={"R": 0.001, "L": 0.0002, "K": 0.1}), LIMITS)
    assert ident.quality() == {"R": "none", "L": "ok", "K": "none"}
    assert "together with K" in ident.reasons["R"]


@pytest.mark.parametrize("std", [math.inf, math.nan])
def test_infinite_or_nan_std_is_not_identified(std: float):
    ident = identify(_estimate("field", std={"R": std, "L": 0.00005}), FIELD_LIMITS)
    assert ident.quality() == {"R": "none", "L": "ok"}


def test_the_limits_are_the_callers():
    est = _estimate(std={"R": 0.07, "L": 0.0002, "K": 0.0001})  # 2 % on R
    assert identify(est, LIMITS).quality()["R"] == "none"
    assert identify(est, {**LIMITS, "R": 0.05}).quality()["R"] == "ok"
