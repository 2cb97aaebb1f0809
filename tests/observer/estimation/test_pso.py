"""The paper's PSO: eq. (2), schedules, determinism, bounds, warm start, stopping."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation.pso import ParticleSwarm, PSOResult, coefficients, minimize


def sphere(x: np.ndarray) -> np.ndarray:
    return np.sum((x - 0.3) ** 2, axis=1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return 100 * (x[:, 1] - x[:, 0] ** 2) ** 2 + (1 - x[:, 0]) ** 2


BOX = [(-2.0, 2.0), (-2.0, 2.0)]


@pytest.mark.parametrize(
    ("schedule", "iteration", "expected"),
    [
        ("social", 0, (0.1, 1.5)),
        ("social", 77, (0.1, 1.5)),
        ("individual", 5, (1.5, 0.1)),
        ("s-k", 0, (0.1, 1.5)),
        ("s-k", 50, (0.6, 1.0)),
        ("s-k", 140, (1.5, 0.1)),
        ("s-k", 400, (1.5, 0.1)),
        ("k-s", 0, (1.5, 0.1)),
        ("k-s", 70, (0.8, 0.8)),
        ("k-s", 1000, (0.1, 1.5)),
        ((1.2, 0.9), 33, (1.2, 0.9)),
    ],
)
def test_coefficient_schedules(schedule, iteration, expected):
    assert coefficients(schedule, iteration) == pytest.approx(expected)


def test_transition_moves_by_one_hundredth_per_iteration():
    c1 = [coefficients("s-k", i)[0] for i in range(141)]
    assert np.allclose(np.diff(c1), 0.01)


def test_unknown_schedule_is_rejected_with_the_choices():
    with pytest.raises(ValueError, match="s-k"):
        ParticleSwarm(sphere, BOX, schedule="sk")


def test_same_seed_same_result_and_other_seed_differs():
    a = minimize(rosenbrock, BOX, max_iterations=60, rng=42)
    b = minimize(rosenbrock, BOX, max_iterations=60, rng=np.random.default_rng(42))
    c = minimize(rosenbrock, BOX, max_iterations=60, rng=43)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history, b.history)
    assert not np.array_equal(a.history, c.history)


@pytest.mark.parametrize("schedule", ["s-k", "k-s", "social", "individual"])
def test_every_schedule_finds_the_sphere_minimum(schedule):
    res = minimize(sphere, BOX, n_particles=40, max_iterations=150, schedule=schedule, rng=1)
    assert isinstance(res, PSOResult)
    np.testing.assert_allclose(res.x, [0.3, 0.3], atol=1e-3)


def test_result_is_frozen_and_counts_evaluations():
    res = minimize(sphere, BOX, n_particles=20, max_iterations=30, rng=0)
    assert res.n_iterations == 30
    assert res.n_evaluations == 20 * 31
    assert res.history.shape == (31,)
    assert np.all(np.diff(res.history) <= 0)  # best-so-far never worsens
    with pytest.raises(AttributeError):
        res.cost = 0.0  # type: ignore[misc]


def test_particles_never_leave_the_bounds():
    seen = []

    def cost(x):
        seen.append(x.copy())
        return rosenbrock(x)

    # Optimum (1, 1) lies outside this box: particles press against the wall.
    minimize(cost, [(-2.0, 0.5), (-2.0, 0.5)], max_iterations=50, rng=3)
    allx = np.concatenate(seen)
    assert allx[:, 0].max() <= 0.5 and allx[:, 1].max() <= 0.5
    assert allx.min() >= -2.0


def test_tolerance_stops_early_and_says_why():
    res = minimize(sphere, BOX, max_iterations=1000, tol=1e-6, patience=5, rng=0)
    assert res.converged
    assert res.n_iterations < 1000
    assert "tol" in res.message


def test_warm_start_places_a_particle_at_x0():
    solver = ParticleSwarm(sphere, BOX, x0=[0.3, 0.3], init_bounds=[(0.2, 0.4), (0.2, 0.4)], rng=0)
    assert solver.best_cost == 0.0
    np.testing.assert_array_equal(solver.best_position, [0.3, 0.3])


def test_init_bounds_with_exploring_fraction():
    solver = ParticleSwarm(
        sphere, BOX, n_particles=100, init_bounds=[(0.0, 0.1), (0.0, 0.1)],
        explore_fraction=0.2, rng=0,
    )  # fmt: skip
    inside = np.all((solver.x >= 0.0) & (solver.x <= 0.1), axis=1)
    assert 75 <= inside.sum() <= 85  # 80 local, 20 over the whole box (a few may land inside)


def test_stepping_solver_matches_minimize():
    solver = ParticleSwarm(rosenbrock, BOX, rng=7)
    for _ in range(25):
        solver.step()
    res = minimize(rosenbrock, BOX, max_iterations=25, rng=7)
    assert solver.best_cost == res.cost


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"bounds": [(1.0, 0.0)]}, "low < high"),
        ({"bounds": [(0.0, np.inf)]}, "finite"),
        ({"n_particles": 1}, "n_particles"),
        ({"w": -0.1}, "inertia"),
        ({"explore_fraction": 1.5}, "explore_fraction"),
        ({"x0": [0.0, 0.0, 0.0]}, "x0"),
    ],
)
def test_invalid_options_are_rejected_with_a_specific_message(kwargs, match):
    args = {"bounds": BOX} | kwargs
    with pytest.raises(ValueError, match=match):
        ParticleSwarm(sphere, **args)


def test_cost_of_wrong_shape_is_reported():
    with pytest.raises(ValueError, match=r"\(n_particles, n_params\)"):
        ParticleSwarm(lambda x: np.zeros((len(x), 2)), BOX)
