"""The armature estimator's stages, each run alone: swarm, polish, EIV compensation, uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation import armature_search_range, estimate_armature
from observer.estimation.armature import (
    ArmatureWindow,
    EivCorrection,
    armature_std,
    armature_swarm,
    eiv_compensation,
    polish_armature,
)
from observer.estimation.uncertainty import crlb_std

SWARM = dict(
    n_particles=40, max_iterations=40, schedule="s-k", w=0.7, x0=None, init_range=None,
    explore_fraction=0.0, tol=0.0,
)  # fmt: skip


@pytest.fixture(scope="module")
def window(p12_recording):
    w = p12_recording.slice_time(2.0, 3.0)
    return ArmatureWindow.from_signals(w["va"], w["ia"], w["if"], w["omega"], w.dt)


def _stages(window, seed):
    rng = np.random.default_rng(seed)
    bounds = armature_search_range(window.va, window.ia, window.i_f, window.omega, window.dt)
    result = armature_swarm(window, bounds, rng=rng, **SWARM)
    fit = polish_armature(window, result, bounds)
    eiv = eiv_compensation(
        window, fit.point, bounds, n_particles=40, max_iterations=40, schedule="s-k", w=0.7,
        rng=rng,
    )  # fmt: skip
    return bounds, result, fit, eiv


def test_the_stages_in_order_are_estimate_armature(window):
    _, result, fit, eiv = _stages(window, seed=3)
    est = estimate_armature(
        window.va, window.ia, window.i_f, window.omega, window.dt, rng=3, n_particles=40,
        max_iterations=40,
    )  # fmt: skip
    assert est.pso.cost == result.cost
    assert est.resistance_ohm == eiv.point.resistance_ohm
    assert est.inductance_h == eiv.point.inductance_h
    assert est.emf_constant_h == eiv.point.emf_constant_h
    assert est.input_noise_var == eiv.input_noise_var
    assert dict(est.std) == armature_std(window, fit, eiv)


def test_polish_lowers_the_swarms_residual(window):
    _, result, fit, _ = _stages(window, seed=4)
    r, ell = 10.0**result.x
    _, _, swarm_residual = window.linear(r, ell)
    assert fit.point.residual @ fit.point.residual <= swarm_residual @ swarm_residual
    assert fit.jacobian.shape == (window.n_samples, 4)  # ln R, ln L, i0, K


def test_without_a_correction_the_uncertainty_is_the_sandwich_bound(window):
    _, _, fit, _ = _stages(window, seed=5)
    plain = EivCorrection(fit.point, 0.0, np.zeros(3))
    std = armature_std(window, fit, plain)
    tau_samples = np.exp(fit.theta[1] - fit.theta[0]) / window.dt
    bound = crlb_std(fit.jacobian, fit.point.residual, tau_samples)
    assert std["R"] == pytest.approx(fit.point.resistance_ohm * bound[0])
    assert std["L"] == pytest.approx(fit.point.inductance_h * bound[1])
    assert std["K"] == pytest.approx(bound[3])


def test_a_correction_moves_the_estimate_by_at_most_the_search_factor(window):
    _, _, fit, eiv = _stages(window, seed=6)
    assert eiv.input_noise_var >= 0.0
    ratio = eiv.point.inductance_h / fit.point.inductance_h
    assert 1 / 1.5 <= ratio <= 1.5
    assert np.all(eiv.bias_bound >= 0.0)
