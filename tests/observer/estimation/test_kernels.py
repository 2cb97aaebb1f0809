"""The discrete winding models and the swarm cost kernels."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation import kernels


def test_rl_step_response_matches_analytic_solution():
    r, ell, dt, i0, v = 185.0, 50.0, 1e-3, 0.2, 220.0
    n = 3000
    i = kernels.simulate_rl(r, ell, i0, np.full(n, v), dt)
    t = np.arange(n) * dt
    analytic = v / r + (i0 - v / r) * np.exp(-r * t / ell)
    np.testing.assert_allclose(i, analytic, rtol=1e-12, atol=1e-12)


def test_rl_response_independent_of_sample_rate():
    """Exact ZOH: a step sampled at 100 Hz and at 10 kHz agree at common instants."""
    r, ell, v = 3.5, 0.02, 100.0
    coarse = kernels.simulate_rl(r, ell, 0.0, np.full(11, v), 1e-2)
    fine = kernels.simulate_rl(r, ell, 0.0, np.full(1001, v), 1e-4)
    np.testing.assert_allclose(coarse, fine[::100], rtol=1e-11)


def test_armature_with_constant_emf_is_rl_with_reduced_voltage():
    n, dt = 500, 1e-4
    va = np.full(n, 200.0)
    i_f = np.full(n, 1.2)
    omega = np.full(n, 100.0)
    emf = kernels.emf_input(i_f, omega)
    np.testing.assert_allclose(emf, 120.0)
    k = 1.1
    ia = kernels.simulate_armature(3.5, 0.02, k, 0.0, va, emf, dt)
    expected = kernels.simulate_rl(3.5, 0.02, 0.0, va - k * 120.0, dt)
    np.testing.assert_allclose(ia, expected, rtol=1e-12)


def _excitation(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.repeat(rng.uniform(100, 300, n // 100 + 1), 100)[:n]


def test_rl_swarm_cost_equals_best_initial_current_least_squares():
    dt, n = 1e-3, 1500
    v = _excitation(n, 0)
    y = kernels.simulate_rl(185.0, 50.0, 0.7, v, dt) + np.random.default_rng(1).normal(0, 0.01, n)
    rng = np.random.default_rng(2)
    positions = np.column_stack([rng.uniform(1.5, 3, 7), rng.uniform(0, 2.5, 7)])
    costs = kernels.rl_swarm_costs(positions, v, y, dt, True)
    for (lr, ll), cost in zip(positions, costs, strict=True):
        r, ell = 10**lr, 10**ll
        forced = kernels.simulate_rl(r, ell, 0.0, v, dt)
        free = kernels.simulate_rl(r, ell, 1.0, np.zeros(n), dt)
        i0 = np.dot(y - forced, free) / np.dot(free, free)
        resid = y - forced - i0 * free
        assert cost == pytest.approx(resid @ resid, rel=1e-9)
    # Linear-scale positions give the same costs.
    linear = kernels.rl_swarm_costs(10**positions, v, y, dt, False)
    np.testing.assert_allclose(linear, costs, rtol=1e-12)


def test_rl_swarm_cost_is_minimal_at_truth_without_noise():
    dt, n = 1e-3, 1500
    v = _excitation(n, 3)
    y = kernels.simulate_rl(185.0, 50.0, 1.0, v, dt)
    truth = np.log10([[185.0, 50.0]])
    assert kernels.rl_swarm_costs(truth, v, y, dt, True)[0] < 1e-9
    off = truth + np.array([[0.01, 0.0], [0.0, 0.01], [-0.01, 0.0], [0.0, -0.01]])
    assert np.all(kernels.rl_swarm_costs(off, v, y, dt, True) > 1e-4)


def test_armature_swarm_cost_projects_emf_constant_and_initial_current():
    dt, n = 1e-4, 3000
    va = _excitation(n, 4)
    i_f = np.full(n, 1.19)
    omega = np.linspace(0, 150, n)
    emf = kernels.emf_input(i_f, omega)
    y = kernels.simulate_armature(3.5, 0.02, 1.12, 2.0, va, emf, dt)
    truth = np.log10([[3.5, 0.02]])
    assert kernels.armature_swarm_costs(truth, va, emf, y, dt, True, np.nan)[0] < 1e-9
    # Holding K at the true value gives the same minimum; a wrong K does not.
    assert kernels.armature_swarm_costs(truth, va, emf, y, dt, True, 1.12)[0] < 1e-9
    assert kernels.armature_swarm_costs(truth, va, emf, y, dt, True, 1.0)[0] > 1e-3


def test_subnormal_free_response_is_flushed_not_nan():
    """Particles with fast decay must not produce NaN or be slowed by subnormals."""
    dt, n = 1e-3, 2000
    v = _excitation(n, 5)
    y = kernels.simulate_rl(185.0, 50.0, 0.0, v, dt)
    positions = np.array([[3.0, -1.0], [2.0, 0.5], [1.0, 3.0]])
    costs = kernels.rl_swarm_costs(positions, v, y, dt, True)
    assert np.all(np.isfinite(costs)) and np.all(costs > 0)


def test_pso_update_keeps_particles_in_bounds():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (50, 3))
    v = rng.normal(0, 5, (50, 3))
    lower, upper = np.zeros(3), np.ones(3)
    for _ in range(20):
        kernels.pso_update(
            x, v, x.copy(), np.array([2.0, -1.0, 0.5]), rng.random((50, 3)), rng.random((50, 3)),
            0.7, 1.5, 1.5, lower, upper, np.full(3, 10.0),
        )  # fmt: skip
        assert np.all(x >= lower) and np.all(x <= upper)


@pytest.mark.parametrize(("n", "p", "batch"), [(2000, 3, 181), (500, 2, 0), (40, 5, 11), (7, 1, 7)])
def test_score_products_are_the_sandwich_bounds_plain_products(n, p, batch):
    """J'J and the sliding runs' sum of s s' against numpy's products of every run's sum."""
    rng = np.random.default_rng(n)
    jac = rng.standard_normal((n, p)) * np.logspace(-3, 3, p)
    residual = np.convolve(rng.standard_normal(n + 9), np.ones(10), "valid")
    jtj, meat = kernels.score_products(jac, residual, batch)
    np.testing.assert_allclose(jtj, jac.T @ jac, rtol=1e-12)
    if batch == 0:
        assert not meat.any()
        return
    scores = jac * residual[:, None]
    sums = np.array([scores[k : k + batch].sum(axis=0) for k in range(n + 1 - batch)])
    np.testing.assert_allclose(meat, sums.T @ sums, rtol=1e-10, atol=1e-12 * np.abs(meat).max())


def test_autocovariances_are_the_lagged_dot_products():
    x = np.random.default_rng(1).standard_normal(300)
    expected = [x[:-lag] @ x[lag:] / x.size for lag in range(1, 51)]
    np.testing.assert_allclose(kernels.autocovariances(x, 50), expected, rtol=1e-12, atol=1e-15)
