"""The moment kernels: the ZOH model as a special case, exact for any known voltage, segments."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer.estimation import intersample_kernels as ik
from observer.estimation import kernels
from observer.estimation.intersample import Segments


@pytest.fixture(scope="module")
def window(p12_recording):
    w = p12_recording.slice_time(2.0, 3.0)
    return {c: np.array(w[c]) for c in ("va", "ia", "vf", "if", "omega")} | {"dt": w.dt}


def _hold(v):
    mu = np.zeros((v.size - 1, 3))
    mu[:, 0] = v[:-1]
    return mu


def test_held_moments_reproduce_the_zoh_swarm_costs(window):
    dt, n = window["dt"], window["va"].size
    whole = Segments.whole(n)
    field_pos = np.log10([[185.0, 50.0], [150.0, 40.0], [200.0, 70.0]])
    old = kernels.rl_swarm_costs(field_pos, window["vf"], window["if"], dt, True, 0.0)
    new = ik.moment_swarm_costs(
        field_pos, _hold(window["vf"]), _hold(window["vf"]), window["if"], whole.starts,
        whole.ends, dt, True, ik.EMF_NONE, 0.0, 0.0,
    )  # fmt: skip
    assert new == pytest.approx(old, rel=1e-9)
    emf = kernels.emf_input(window["if"], window["omega"])
    arm_pos = np.log10([[3.5, 0.02], [3.0, 0.03], [4.0, 0.015]])
    for mode, k, noise in ((ik.EMF_FIT, math.nan, 0.0), (ik.EMF_HELD, 1.12, 0.5)):
        old = kernels.armature_swarm_costs(
            arm_pos, window["va"], emf, window["ia"], dt, True, k, noise
        )
        new = ik.moment_swarm_costs(
            arm_pos, _hold(window["va"]), _hold(emf), window["ia"], whole.starts, whole.ends,
            dt, True, mode, 0.0 if mode == ik.EMF_FIT else k, noise,
        )  # fmt: skip
        assert new == pytest.approx(old, rel=1e-8)


def test_the_update_is_exact_for_a_voltage_known_between_samples():
    # v(t) = 100 + 40 sin(2 pi 90 t), a winding of tau = 2.5 samples, integrated finely.
    r, ell, dt, n, fine = 2.0, 0.0025, 0.5e-3, 400, 200
    h = dt / fine
    t = np.arange(n * fine + 1) * h
    v = 100 + 40 * np.sin(2 * np.pi * 90 * t)
    i = np.empty_like(t)
    i[0] = 1.0
    a = math.exp(-r * h / ell)
    for k in range(t.size - 1):  # exact for a voltage linear over each fine step
        v0, v1 = v[k], v[k + 1]
        slope = (v1 - v0) / h
        i[k + 1] = a * i[k] + (1 - a) / r * v0 + slope / r * (h - ell / r * (1 - a))
    u = np.linspace(0, 1, fine + 1)
    mu = np.empty((n, 3))
    for k in range(n):
        seg = v[k * fine : (k + 1) * fine + 1]
        for j, leg in enumerate((np.ones_like(u), 2 * u - 1, 6 * u**2 - 6 * u + 1)):
            mu[k, j] = np.trapezoid(seg * leg, u)
    y = i[::fine]
    whole = Segments.whole(n + 1)
    out, initial = np.empty(n + 1), np.empty(1)
    ik.moment_residual(
        r, ell, 0.0, mu, mu, y, whole.starts, whole.ends, dt, False, out, initial
    )  # fmt: skip
    # x = R*T/L = 0.4: the quadratic weight's error is ~x^3/2000.
    assert np.max(np.abs(out)) < 1e-5 * np.max(np.abs(y))
    assert initial[0] == pytest.approx(1.0, abs=1e-4)
    # The held model misses: the voltage is not constant between samples.
    out_hold = np.empty(n + 1)
    ik.moment_residual(
        r, ell, 0.0, _hold(v[::fine]), mu, y, whole.starts, whole.ends, dt, False, out_hold,
        initial,
    )  # fmt: skip
    assert np.max(np.abs(out_hold)) > 100 * np.max(np.abs(out))


def test_segments_are_independent_simulations(window):
    dt, v, y = window["dt"], window["vf"], window["if"]
    mu = _hold(v)
    starts, ends = np.array([0, 600, 1300]), np.array([500, 1200, 1999])
    pos = np.log10([[185.0, 50.0], [170.0, 60.0]])
    together = ik.moment_swarm_costs(
        pos, mu, mu, y, starts, ends, dt, True, ik.EMF_NONE, 0.0, 0.0
    )  # fmt: skip
    apart = sum(
        ik.moment_swarm_costs(
            pos, mu, mu, y, starts[i : i + 1], ends[i : i + 1], dt, True, ik.EMF_NONE, 0.0, 0.0
        )
        for i in range(3)
    )
    assert together == pytest.approx(apart, rel=1e-12)


def test_coefficients_are_continuous_where_the_series_takes_over():
    x = ik._SERIES_X
    below = ik.moment_coefficients(1.0, 1.0 / (x * (1 - 1e-9)), 1.0)
    above = ik.moment_coefficients(1.0, 1.0 / (x * (1 + 1e-9)), 1.0)
    assert below == pytest.approx(above, rel=1e-7)
    # and they match the defining integrals
    for x in (1e-4, 0.05, 0.5, 3.0):
        a, c0, c1, c2 = ik.moment_coefficients(1.0, 1.0 / x, 1.0)
        u = np.linspace(0, 1, 200001)
        w = np.exp(-x * (1 - u))
        for c, j, leg in ((c0, 0, 1.0), (c1, 1, 2 * u - 1), (c2, 2, 6 * u**2 - 6 * u + 1)):
            assert c == pytest.approx(x * (2 * j + 1) * np.trapezoid(w * leg, u), rel=1e-6)


@pytest.mark.parametrize("n_particles", [1, 3, 4, 5, 9, 23, 24])
@pytest.mark.parametrize("mode", [ik.EMF_NONE, ik.EMF_FIT, ik.EMF_HELD])
def test_the_fast_swarm_cost_equals_the_plain_reference(window, n_particles, mode):
    """The vectorised kernel computes the plain kernel's cost to rounding, for every layout.

    Segments of 1, 2, 3 and 5 samples exercise the shortest runs of a block;
    particle counts that are not whole blocks (4 particles with ``K`` fitted,
    8 without) exercise the padding; a held input (higher moments 0) is also
    taken by the cheaper loop.
    """
    dt, n = window["dt"], window["va"].size
    rng = np.random.default_rng(n_particles + 10 * mode)
    voltage, current = (window["va"], window["ia"]) if mode else (window["vf"], window["if"])
    emf = kernels.emf_input(window["if"], window["omega"])
    box = np.log10([[2.5, 0.01], [5.0, 0.04]]) if mode else np.log10([[150, 30.0], [220, 80]])
    pos = rng.uniform(box[0], box[1], (n_particles, 2))
    starts = np.array([0, 10, 20, 30, 40, 700, 1500])
    ends = np.array([0, 11, 22, 34, 650, 1400, n - 1])
    moments = rng.normal(0.0, 5.0, (n - 1, 3)) + _hold(voltage)
    for mu, mu_emf, n_moments in (
        (_hold(voltage), _hold(emf), 1),
        (_hold(voltage), _hold(emf), 3),
        (moments, _hold(emf) + rng.normal(0.0, 1.0, (n - 1, 3)), 3),
    ):
        for noise_var in (0.0, 0.5):
            args = (pos, mu, mu_emf, current, starts, ends, dt, True, mode, 1.1, noise_var)
            plain = ik.plain_moment_swarm_costs(*args)
            fast = ik.moment_swarm_costs(*args, n_moments)
            # Projecting K out subtracts sums the size of sum(y^2): rounding is relative to them.
            scale = float(current @ current)
            np.testing.assert_allclose(fast, plain, rtol=1e-9, atol=1e-13 * scale)


@pytest.mark.parametrize("mode", [ik.EMF_NONE, ik.EMF_FIT, ik.EMF_HELD])
def test_the_fast_swarm_cost_runs_segments_across_tiles(p12_recording, mode):
    """A segment longer than a tile (the blocks run tile by tile) keeps its states between them."""
    w = p12_recording.slice_time(0.0, 5.0)
    dt = w.dt
    va, ia, vf, i_f = (np.array(w[c]) for c in ("va", "ia", "vf", "if"))
    n = va.size
    assert n > 3 * ik._TILE
    emf = kernels.emf_input(i_f, np.array(w["omega"]))
    voltage, current = (va, ia) if mode else (vf, i_f)
    box = np.log10([[2.5, 0.01], [5.0, 0.04]]) if mode else np.log10([[150, 30.0], [220, 80]])
    pos = np.random.default_rng(mode).uniform(box[0], box[1], (24, 2))
    starts = np.array([0, ik._TILE - 3])
    ends = np.array([ik._TILE - 5, n - 1])
    rng = np.random.default_rng(5)
    mu = _hold(voltage) + rng.normal(0.0, 5.0, (n - 1, 3))
    mu_emf = _hold(emf) + rng.normal(0.0, 1.0, (n - 1, 3))
    args = (pos, mu, mu_emf, current, starts, ends, dt, True, mode, 1.1, 0.0)
    plain = ik.plain_moment_swarm_costs(*args)
    fast = ik.moment_swarm_costs(*args)
    np.testing.assert_allclose(fast, plain, rtol=1e-9, atol=1e-13 * float(current @ current))


@pytest.mark.parametrize("shift", [0.0, 0.3, -0.5, 0.999, 1.2, -1.5])
def test_cubic_moments_stencil_equals_the_cubic_point_by_point(shift):
    """The hoisted stencil of interior intervals is the cubic taken node by node."""
    v = np.cumsum(np.random.default_rng(7).normal(size=60)) + 100.0
    starts, ends = np.array([0, 6, 9, 13]), np.array([4, 7, 11, 59])
    out = np.zeros((v.size - 1, 3))
    ik.interpolated_moments(v, starts, ends, shift, ik.GAUSS_U, ik.GAUSS_W, out)
    expected = np.zeros_like(out)
    for st, en in zip(starts, ends, strict=True):
        m = en - st + 1
        for k in range(m - 1):
            for u, weight in zip(ik.GAUSS_U, ik.GAUSS_W, strict=True):
                val = weight * ik._cubic_point(v, st, m, min(m, 4), k + u + shift)
                expected[st + k] += val * np.array([1.0, 2 * u - 1, 6 * u * u - 6 * u + 1])
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12 * np.max(np.abs(v)))


@pytest.mark.parametrize("x", [1e-4, 0.05, 0.4, 0.999, 1.001, 3.0, 20.0])
def test_the_coefficient_slopes_are_the_coefficients_derivatives(x):
    # Both branches (series below x = 1, closed forms above), against central differences
    # in ln R (Richardson-extrapolated: a at small x moves by x*h only); the ln L slopes
    # follow from them (see moment_coefficient_slopes).
    r, dt = 2.0, 1e-4
    ell = r * dt / x

    def central(h):
        up = np.array(ik.moment_coefficients(r * math.exp(h), ell, dt))
        down = np.array(ik.moment_coefficients(r * math.exp(-h), ell, dt))
        return (up - down) / (2 * h)

    slopes = np.array(ik.moment_coefficient_slopes(r, ell, dt))
    expected = (4 * central(5e-4) - central(1e-3)) / 3
    # a = 1 - expm1 above the series loses its digits below 1e-16 absolute: so does its slope.
    np.testing.assert_allclose(slopes, expected, rtol=1e-7, atol=1e-9 * np.max(np.abs(expected)))


def _residual(theta, fit_k, k_held, mu, mu_emf, y, starts, ends, dt, has_emf):
    out, initial = np.empty(int(np.sum(ends - starts + 1))), np.empty(starts.size)
    k = theta[2] if fit_k else k_held
    ik.moment_residual(
        math.exp(theta[0]), math.exp(theta[1]), k, mu, mu_emf, y, starts, ends, dt, has_emf,
        out, initial,
    )  # fmt: skip
    return out, initial


@pytest.mark.parametrize("circuit", ["field", "armature", "armature_held_k"])
@pytest.mark.parametrize("moments", ["hold", "smooth"])
def test_the_residual_jacobian_kernel_is_the_residual_and_its_derivatives(window, circuit, moments):
    from observer.estimation.intersample import smooth_moments

    dt = window["dt"]
    starts, ends = np.array([0, 600, 1300]), np.array([500, 1200, 1999])
    seg = Segments(starts, ends, window["vf"].size)
    v, y = (window["vf"], window["if"]) if circuit == "field" else (window["va"], window["ia"])
    emf = kernels.emf_input(window["if"], window["omega"])
    if moments == "hold":
        mu, mu_emf = _hold(v), _hold(emf)
    else:
        mu, mu_emf = smooth_moments(v, seg, 0.3), smooth_moments(emf, seg, 0.0)
    mode = {"field": ik.EMF_NONE, "armature": ik.EMF_FIT, "armature_held_k": ik.EMF_HELD}[circuit]
    fit_k, has_emf = mode == ik.EMF_FIT, mode != ik.EMF_NONE
    # Near, not at, each winding's values: the residual and its slopes are not small.
    r, ell, k = (170.0, 55.0, 0.0) if circuit == "field" else (3.2, 0.022, 1.1)
    theta = np.array([math.log(r), math.log(ell), k][: 2 + int(fit_k)])
    p = theta.size
    out, jac = np.empty(seg.covered), np.empty((seg.covered, p))
    initial, normal = np.empty(3), np.empty((p, p + 1))
    ik.moment_residual_jacobian(
        r, ell, k, mu, mu_emf, y, starts, ends, dt, mode, out, jac, initial, normal
    )  # fmt: skip
    args = (fit_k, k, mu, mu_emf, y, starts, ends, dt, has_emf)
    plain, plain_initial = _residual(theta, *args)
    # The residual is the residual kernel's, to rounding (the compiler fuses its products
    # into FMAs as the surrounding code lets it).
    scale = np.max(np.abs(plain))
    np.testing.assert_allclose(out, plain, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(initial, plain_initial, rtol=1e-13)
    for j in range(p):
        h = 1e-5 * max(abs(theta[j]), 1.0)
        step = np.zeros(p)
        step[j] = h
        central = (_residual(theta + step, *args)[0] - _residual(theta - step, *args)[0]) / (2 * h)
        assert np.linalg.norm(jac[:, j] - central) < 1e-7 * np.linalg.norm(central)
    np.testing.assert_allclose(normal[:, :p], jac.T @ jac, rtol=1e-12)
    np.testing.assert_allclose(normal[:, p], jac.T @ out, rtol=1e-9)
