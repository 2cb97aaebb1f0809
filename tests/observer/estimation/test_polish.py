"""The polish: Levenberg-Marquardt with the winding problem's exact sensitivities."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from observer.estimation.intersample import build_input
from observer.estimation.polish import jacobian, levenberg_marquardt
from observer.estimation.problem import WindingProblem
from observer.estimation.ranges import armature_search_range, field_search_range


@pytest.fixture(scope="module")
def window(p12_recording):
    w = p12_recording.slice_time(2.0, 3.0)
    return {c: np.array(w[c]) for c in ("va", "ia", "vf", "if", "omega")} | {"dt": w.dt}


def _problem(window, circuit, model):
    """The window's problem in three segments (as around a clipped sample) and its polish's
    limits; ``smooth`` also fits the shift."""
    w, dt = window, window["dt"]
    valid = np.ones(w["va"].size, dtype=bool)
    valid[600:605] = valid[1300] = False
    if circuit == "field":
        v, i, emf = w["vf"], w["if"], None
        bounds = field_search_range(w["vf"], w["if"], dt)
    else:
        v, i, emf = w["va"], w["ia"], w["if"] * w["omega"]
        bounds = armature_search_range(w["va"], w["ia"], w["if"], w["omega"], dt)
    inp = build_input(v, model, shift=0.1, valid=valid, dt=dt)
    problem = WindingProblem(v, i, dt, inp, emf, fit_shift=model == "smooth")
    assert problem.segments.count == 3
    return problem, problem.limits(bounds.log_bounds())


def _start(problem, circuit):
    """Parameters near, not at, the P-12's: the polish has steps to take."""
    resistance, inductance = (170.0, 55.0) if circuit == "field" else (3.2, 0.022)
    return problem.theta0(resistance, inductance, 1.1 if problem.fits_k else None)


@pytest.mark.parametrize("circuit", ["field", "armature"])
@pytest.mark.parametrize("model", ["hold", "smooth"])
def test_the_exact_jacobian_is_the_central_difference(window, circuit, model):
    problem, _ = _problem(window, circuit, model)
    theta = _start(problem, circuit)
    r, jac, jtj, grad = problem.residual_and_jacobian(theta)
    np.testing.assert_array_equal(r, problem.residual(theta))
    central = jacobian(problem.residual, theta)
    core = 2 + int(problem.fits_k)
    for j in range(core):
        assert np.linalg.norm(jac[:, j] - central[:, j]) < 1e-7 * np.linalg.norm(central[:, j])
    # A fitted shift keeps the forward difference the polish took before (the voltage's
    # moments move with it).
    forward = jacobian(problem.residual, theta, r)
    np.testing.assert_array_equal(jac[:, core:], forward[:, core:])
    np.testing.assert_allclose(jtj, jac.T @ jac, rtol=1e-10, atol=1e-12 * np.abs(jtj).max())
    np.testing.assert_allclose(grad, jac.T @ r, rtol=1e-8, atol=1e-12 * np.abs(grad).max())


@pytest.mark.parametrize("circuit", ["field", "armature"])
@pytest.mark.parametrize("model", ["hold", "smooth"])
@pytest.mark.parametrize("on_trials", [True, False])
def test_the_exact_jacobian_polishes_to_the_same_estimate(window, circuit, model, on_trials):
    problem, (lower, upper) = _problem(window, circuit, model)
    theta0 = _start(problem, circuit)
    kw = dict(lower=lower, upper=upper)
    by_differences = levenberg_marquardt(problem.residual, theta0.copy(), **kw)
    exact = levenberg_marquardt(
        problem.residual, theta0.copy(), residual_and_jacobian=problem.residual_and_jacobian,
        jacobian_on_trials=on_trials, **kw,
    )  # fmt: skip
    theta_d, r_d, jac_d = by_differences
    theta_e, r_e, _ = exact
    cost_d, cost_e = float(r_d @ r_d), float(r_e @ r_e)
    # Both stop where a step gains less than rtol (1e-8) of the cost, or where steps creep
    # along a direction the window does not identify (the field's Lf here): the exact
    # sensitivities never end higher, and the estimates agree to a small share of their
    # spread (the Cramer-Rao bound).
    assert cost_e <= cost_d * (1 + 1e-8)
    spread = np.sqrt(cost_d / r_d.size * np.diag(np.linalg.inv(jac_d.T @ jac_d)))
    assert np.all(np.abs(theta_e - theta_d) < 0.05 * spread)


def test_a_direction_the_residual_does_not_see_is_left_where_it_was():
    # An exactly flat cost along theta[1] (J'J singular), as Lf under a constant field
    # voltage nearly is: the polish solves the rest and leaves theta[1] alone.
    t = np.linspace(0.0, 1.0, 200)
    y = 2.0 * np.exp(-1.5 * t)

    def residual(theta):
        return y - theta[0] * np.exp(-theta[2] * t)

    theta, r, jac = levenberg_marquardt(residual, np.array([1.0, 0.3, 1.0]))
    assert theta[1] == 0.3
    np.testing.assert_allclose(theta[[0, 2]], [2.0, 1.5], rtol=1e-6)
    assert np.all(jac[:, 1] == 0.0)


def test_a_trial_that_overflows_is_rejected_and_the_polish_goes_on():
    # From theta = 0.3 the Gauss-Newton step runs to the upper limit 2, where
    # exp(1200 t) overflows: those trials are refused, not kept, no warning escapes, and
    # the shorter steps that follow reach 0.5.
    t = np.linspace(0.0, 1.0, 50)
    finite = []

    def residual(theta):
        r = np.exp((theta[0] - 0.5) * 800 * t) - 1.0
        finite.append(bool(np.all(np.isfinite(r))))
        return r

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        theta, r, _ = levenberg_marquardt(residual, np.array([0.3]), upper=np.array([2.0]))
    assert not all(finite)
    assert np.all(np.isfinite(r))
    assert theta[0] == pytest.approx(0.5, rel=1e-9)
