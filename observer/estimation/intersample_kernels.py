"""Numba kernels for a winding driven by a voltage known between samples by its moments.

The zero-order-hold model of :mod:`observer.estimation.kernels` assumes the
voltage is constant over each sample period. A converter's voltage is not: a
thyristor bridge applies mains sine segments with a jump at every firing, and
the measured samples pass anti-aliasing filters first. Here the voltage over
interval ``k`` (from sample ``k`` to ``k+1``) is described by its first three
Legendre moments::

    mu_j[k] = int_0^1 v(t_k + u*T) * P_j(u) du,   P_0 = 1, P_1 = 2u - 1, P_2 = 6u^2 - 6u + 1

and the winding ``v = R*i + L*di/dt`` is discretised exactly for any voltage
whose weight ``exp(-x*(1-u))`` (``x = R*T/L``) is well represented by a
quadratic over one period (error ~ x^3/2000; x < 0.3 in practice)::

    i[k+1] = a*i[k] + c_0*mu_0[k] + c_1*mu_1[k] + c_2*mu_2[k]
    a = exp(-x),   c_j = (x/R)*(2j+1)*int_0^1 exp(-x*(1-u)) P_j(u) du

A held voltage has ``mu_1 = mu_2 = 0`` and ``c_0 = (1-a)/R``: the ZOH model.

Segments
--------
Where the voltage between two samples is not known (a switching instant falls
inside the interval and the samples do not say when), the simulation restarts:
the window is a list of segments, sample ranges ``[start, end]`` whose
intervals are all known, each with its own initial current solved in closed
form. The EMF constant ``K`` is shared by all segments and also solved in
closed form (variable projection over ``K`` and every segment's ``i0``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from observer.estimation.kernels import geometric_energy

#: Below this, the closed-form weights lose digits to cancellation: use the series,
#: whose terms fall as x^n/n! (16 terms: below 1e-16 relative for x < 1).
_SERIES_X = 1.0
_SERIES_TERMS = 16

#: Free responses are floored (see :data:`observer.estimation.kernels._G_FLOOR`).
_G_FLOOR = 1e-200
_A_FLOOR = 1e-100

#: Below this Gram determinant (relative), K is not identifiable from the window.
_SINGULAR_RTOL = 1e-10

EMF_NONE = 0
"""No EMF term (the field winding)."""
EMF_FIT = 1
"""Fit ``K`` by projection."""
EMF_HELD = 2
"""Hold ``K`` at a given value."""


@njit(nogil=True, cache=True)
def moment_coefficients(
    resistance: float, inductance: float, dt: float
) -> tuple[float, float, float, float]:
    """``(a, c_0, c_1, c_2)`` of the exact update for period ``dt`` (see the module notes)."""
    x = resistance * dt / inductance
    if x < _SERIES_X:
        # w_j = sum_n (-x)^n/n! * int_0^1 s^n P_j(1 - s) ds (s = 1 - u), whose
        # integrals are 1/(n+1), -n/((n+1)(n+2)) and n(n-1)/((n+1)(n+2)(n+3)).
        w0 = 0.0
        w1 = 0.0
        w2 = 0.0
        term = 1.0  # (-x)^n / n!
        for n in range(_SERIES_TERMS):
            w0 += term / (n + 1.0)
            w1 -= term * n / ((n + 1.0) * (n + 2.0))
            w2 += term * n * (n - 1.0) / ((n + 1.0) * (n + 2.0) * (n + 3.0))
            term *= -x / (n + 1.0)
        a = math.exp(-x)
    else:
        om = -math.expm1(-x)
        a = 1.0 - om
        y = 1.0 / x
        m0 = om * y  # int w
        m1 = (1.0 - om * y) * y  # int w u
        m2 = (1.0 - 2.0 * y + 2.0 * y * y * om) * y  # int w u^2
        w0 = m0
        w1 = 2.0 * m1 - m0
        w2 = 6.0 * m2 - 6.0 * m1 + m0
    g = x / resistance
    return a, g * w0, 3.0 * g * w1, 5.0 * g * w2


@njit(nogil=True, cache=True)
def segment_noise_energy(a: float, c0: float, m: int) -> float:
    """Expected sum of squares over a segment of ``m`` samples of unit white input noise.

    Noise on the voltage reaches the simulated current through ``h_j = c_0*a^j``
    (the zeroth moment of white noise is the noise itself); see
    :func:`observer.estimation.kernels.input_noise_energy`.
    """
    aa = a * a
    if aa >= 1.0:
        return c0 * c0 * m * (m - 1) / 2.0
    return c0 * c0 / (1.0 - aa) * (m - geometric_energy(a, m))


@njit(nogil=True, cache=True, fastmath={"contract"})
def plain_moment_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    log_scale: bool,
    emf_mode: int,
    emf_constant: float,
    input_noise_var: float,
) -> np.ndarray:
    """The reference form of :func:`moment_swarm_costs`: the same cost, written plainly.

    The loops run as the equations read (samples outside, particles inside,
    every state in memory); the fast kernel must agree with it to rounding
    (``tests/observer/estimation/test_intersample_kernels.py``) and the
    benchmark measures both (``python -m bench.kernel_speed``).

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(R [ohm], L [H])`` per particle, or their base-10 logarithms.
    mu, mu_emf : (n - 1, 3) arrays
        Legendre moments of the winding voltage (V) and of ``if*omega``
        (A*rad/s) over each interval; ``mu_emf`` is ignored when
        ``emf_mode == EMF_NONE``.
    current : (n,) array
        Measured winding current (A).
    starts, ends : (n_segments,) int arrays
        First and last sample of each segment (inclusive; intervals between
        segments are skipped).
    emf_mode : {EMF_NONE, EMF_FIT, EMF_HELD}
    emf_constant : float
        ``K`` when ``emf_mode == EMF_HELD``.
    input_noise_var : float
        Variance (V^2) of white noise on the voltage whose expected share of
        the cost is subtracted (errors-in-variables compensation).

    Returns
    -------
    (n_particles,) array of sums of squared current error (A^2).
    """
    n_particles = positions.shape[0]
    a = np.empty(n_particles)
    a_g = np.empty(n_particles)
    c0 = np.empty(n_particles)
    c1 = np.empty(n_particles)
    c2 = np.empty(n_particles)
    for p in range(n_particles):
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a[p], c0[p], c1[p], c2[p] = moment_coefficients(r, ell, dt)
        a_g[p] = max(a[p], _A_FLOOR)
    has_emf = emf_mode != EMF_NONE
    k_held = emf_constant if emf_mode == EMF_HELD else 0.0
    fit_k = emf_mode == EMF_FIT
    big_a = np.zeros(n_particles)
    big_b = np.zeros(n_particles)
    big_c = np.zeros(n_particles)
    noise = np.zeros(n_particles)
    f = np.empty(n_particles)
    fe = np.empty(n_particles)
    g = np.empty(n_particles)
    s_dd = np.empty(n_particles)
    s_dg = np.empty(n_particles)
    s_de = np.empty(n_particles)
    s_ee = np.empty(n_particles)
    s_eg = np.empty(n_particles)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        for p in range(n_particles):
            f[p] = 0.0
            fe[p] = 0.0
            g[p] = 1.0
            s_dd[p] = 0.0
            s_dg[p] = 0.0
            s_de[p] = 0.0
            s_ee[p] = 0.0
            s_eg[p] = 0.0
        for k in range(st, en + 1):
            y = current[k]
            last = k == en
            if last:
                m0 = 0.0
                m1 = 0.0
                m2 = 0.0
                e0 = 0.0
                e1 = 0.0
                e2 = 0.0
            else:
                m0 = mu[k, 0]
                m1 = mu[k, 1]
                m2 = mu[k, 2]
                if has_emf:
                    e0 = mu_emf[k, 0]
                    e1 = mu_emf[k, 1]
                    e2 = mu_emf[k, 2]
                    if not fit_k:
                        m0 -= k_held * e0
                        m1 -= k_held * e1
                        m2 -= k_held * e2
                else:
                    e0 = 0.0
                    e1 = 0.0
                    e2 = 0.0
            if fit_k:
                for p in range(n_particles):
                    d = y - f[p]
                    gp = g[p]
                    fep = fe[p]
                    s_dd[p] += d * d
                    s_dg[p] += d * gp
                    s_de[p] += d * fep
                    s_ee[p] += fep * fep
                    s_eg[p] += fep * gp
                    ap = a[p]
                    f[p] = ap * f[p] + c0[p] * m0 + c1[p] * m1 + c2[p] * m2
                    fe[p] = ap * fep + c0[p] * e0 + c1[p] * e1 + c2[p] * e2
                    g[p] = a_g[p] * gp + _G_FLOOR
            else:
                for p in range(n_particles):
                    d = y - f[p]
                    gp = g[p]
                    s_dd[p] += d * d
                    s_dg[p] += d * gp
                    f[p] = a[p] * f[p] + c0[p] * m0 + c1[p] * m1 + c2[p] * m2
                    g[p] = a_g[p] * gp + _G_FLOOR
        m_seg = en - st + 1
        for p in range(n_particles):
            s_gg = geometric_energy(a[p], m_seg)
            big_a[p] += s_dd[p] - s_dg[p] * s_dg[p] / s_gg
            if fit_k:
                big_b[p] += s_de[p] - s_dg[p] * s_eg[p] / s_gg
                big_c[p] += s_ee[p] - s_eg[p] * s_eg[p] / s_gg
            if input_noise_var > 0.0:
                noise[p] += segment_noise_energy(a[p], c0[p], m_seg)
    out = np.empty(n_particles)
    for p in range(n_particles):
        cost = big_a[p]
        if fit_k and big_c[p] > _SINGULAR_RTOL * abs(big_a[p]) + 1e-300:
            cost -= big_b[p] * big_b[p] / big_c[p]
        out[p] = cost - input_noise_var * noise[p]
    return out


# ---------------------------------------------------------------- the fast swarm cost

#: Particles are processed in whole AVX2 vectors of doubles: the swarm is padded
#: to a multiple of this (the padding repeats the last particle).
LANES = 4

#: Rows of the particle-major work array of :func:`moment_swarm_costs`: the
#: states and sums one particle carries along a segment, then its constants.
#: ``h = f/c_0`` and ``h_e = f_e/c_0`` are the forced responses scaled so that a
#: held input enters without a product; ``r_j = c_j/c_0``.
_H, _HE, _G, _SDD, _SDG, _SDE, _SEE, _SEG, _A, _C0, _AG, _R1, _R2 = range(13)
_ROWS = 13

#: FMAs per particle and sample of the inner loops: (fit K?, moments) -> count.
#: Field or K held: d, s_dd, s_dg, h, g (+2 for the moments' input); K fitted:
#: also h_e, s_de, s_ee, s_eg (+2 more for its moments).
FMAS_PER_PARTICLE_SAMPLE = {(False, 1): 5, (False, 3): 7, (True, 1): 9, (True, 3): 13}


@njit(nogil=True, cache=True, fastmath={"contract"})
def _moment(mu: np.ndarray, mu_emf: np.ndarray, held: bool, k_held: float, k: int, j: int) -> float:
    """Moment ``j`` of interval ``k`` of the winding voltage, less ``K*`` EMF when ``K`` is held."""
    if held:
        return mu[k, j] - k_held * mu_emf[k, j]
    return mu[k, j]


@njit(nogil=True, cache=True, fastmath={"contract"})
def _plain_hold(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, held: bool,
    k_held: float, st: int, en: int,
) -> int:  # fmt: skip
    """Intervals of a segment in fours, held input, no fitted ``K``: the next interval left.

    Each particle's state is loaded and stored once per four samples, so the
    loop is bound by its FMAs, not by memory (one pass per sample is bound by
    the stores, at about half the speed).
    """
    width = w.shape[1]
    k = st
    while k + 4 <= en:
        y0, y1, y2, y3 = y[k], y[k + 1], y[k + 2], y[k + 3]
        u0 = _moment(mu, mu_emf, held, k_held, k, 0)
        u1 = _moment(mu, mu_emf, held, k_held, k + 1, 0)
        u2 = _moment(mu, mu_emf, held, k_held, k + 2, 0)
        u3 = _moment(mu, mu_emf, held, k_held, k + 3, 0)
        for j in range(width):
            h = w[_H, j]
            g = w[_G, j]
            s = w[_SDD, j]
            t = w[_SDG, j]
            a = w[_A, j]
            c = w[_C0, j]
            ag = w[_AG, j]
            d = y0 - c * h
            s += d * d
            t += d * g
            h = a * h + u0
            g = ag * g + _G_FLOOR
            d = y1 - c * h
            s += d * d
            t += d * g
            h = a * h + u1
            g = ag * g + _G_FLOOR
            d = y2 - c * h
            s += d * d
            t += d * g
            h = a * h + u2
            g = ag * g + _G_FLOOR
            d = y3 - c * h
            w[_SDD, j] = s + d * d
            w[_SDG, j] = t + d * g
            w[_H, j] = a * h + u3
            w[_G, j] = ag * g + _G_FLOOR
        k += 4
    return k


@njit(nogil=True, cache=True, fastmath={"contract"})
def _plain_moments(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, held: bool,
    k_held: float, st: int, en: int,
) -> int:  # fmt: skip
    """:func:`_plain_hold` with three moments per interval."""
    width = w.shape[1]
    k = st
    while k + 4 <= en:
        y0, y1, y2, y3 = y[k], y[k + 1], y[k + 2], y[k + 3]
        p0 = _moment(mu, mu_emf, held, k_held, k, 0)
        q0 = _moment(mu, mu_emf, held, k_held, k, 1)
        z0 = _moment(mu, mu_emf, held, k_held, k, 2)
        p1 = _moment(mu, mu_emf, held, k_held, k + 1, 0)
        q1 = _moment(mu, mu_emf, held, k_held, k + 1, 1)
        z1 = _moment(mu, mu_emf, held, k_held, k + 1, 2)
        p2 = _moment(mu, mu_emf, held, k_held, k + 2, 0)
        q2 = _moment(mu, mu_emf, held, k_held, k + 2, 1)
        z2 = _moment(mu, mu_emf, held, k_held, k + 2, 2)
        p3 = _moment(mu, mu_emf, held, k_held, k + 3, 0)
        q3 = _moment(mu, mu_emf, held, k_held, k + 3, 1)
        z3 = _moment(mu, mu_emf, held, k_held, k + 3, 2)
        for j in range(width):
            h = w[_H, j]
            g = w[_G, j]
            s = w[_SDD, j]
            t = w[_SDG, j]
            a = w[_A, j]
            c = w[_C0, j]
            ag = w[_AG, j]
            r1 = w[_R1, j]
            r2 = w[_R2, j]
            d = y0 - c * h
            s += d * d
            t += d * g
            h = a * h + (p0 + r1 * q0 + r2 * z0)
            g = ag * g + _G_FLOOR
            d = y1 - c * h
            s += d * d
            t += d * g
            h = a * h + (p1 + r1 * q1 + r2 * z1)
            g = ag * g + _G_FLOOR
            d = y2 - c * h
            s += d * d
            t += d * g
            h = a * h + (p2 + r1 * q2 + r2 * z2)
            g = ag * g + _G_FLOOR
            d = y3 - c * h
            w[_SDD, j] = s + d * d
            w[_SDG, j] = t + d * g
            w[_H, j] = a * h + (p3 + r1 * q3 + r2 * z3)
            w[_G, j] = ag * g + _G_FLOOR
        k += 4
    return k


@njit(nogil=True, cache=True, fastmath={"contract"})
def _plain_tail(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, held: bool,
    k_held: float, k0: int, en: int,
) -> None:  # fmt: skip
    """Intervals ``k0 .. en-1`` one at a time, then the segment's last sample ``en``."""
    width = w.shape[1]
    for k in range(k0, en):
        yk = y[k]
        p = _moment(mu, mu_emf, held, k_held, k, 0)
        q = _moment(mu, mu_emf, held, k_held, k, 1)
        z = _moment(mu, mu_emf, held, k_held, k, 2)
        for j in range(width):
            h = w[_H, j]
            g = w[_G, j]
            d = yk - w[_C0, j] * h
            w[_SDD, j] += d * d
            w[_SDG, j] += d * g
            w[_H, j] = w[_A, j] * h + (p + w[_R1, j] * q + w[_R2, j] * z)
            w[_G, j] = w[_AG, j] * g + _G_FLOOR
    yk = y[en]
    for j in range(width):
        d = yk - w[_C0, j] * w[_H, j]
        w[_SDD, j] += d * d
        w[_SDG, j] += d * w[_G, j]


@njit(nogil=True, cache=True, fastmath={"contract"})
def _fit_hold(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, st: int, en: int
) -> int:
    """Intervals of a segment in fours, held input, ``K`` fitted: the next interval left."""
    width = w.shape[1]
    k = st
    while k + 4 <= en:
        y0, y1, y2, y3 = y[k], y[k + 1], y[k + 2], y[k + 3]
        u0, u1, u2, u3 = mu[k, 0], mu[k + 1, 0], mu[k + 2, 0], mu[k + 3, 0]
        e0, e1, e2, e3 = mu_emf[k, 0], mu_emf[k + 1, 0], mu_emf[k + 2, 0], mu_emf[k + 3, 0]
        for j in range(width):
            h = w[_H, j]
            he = w[_HE, j]
            g = w[_G, j]
            sdd = w[_SDD, j]
            sdg = w[_SDG, j]
            sde = w[_SDE, j]
            see = w[_SEE, j]
            seg = w[_SEG, j]
            a = w[_A, j]
            c = w[_C0, j]
            ag = w[_AG, j]
            d = y0 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + u0
            he = a * he + e0
            g = ag * g + _G_FLOOR
            d = y1 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + u1
            he = a * he + e1
            g = ag * g + _G_FLOOR
            d = y2 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + u2
            he = a * he + e2
            g = ag * g + _G_FLOOR
            d = y3 - c * h
            w[_SDD, j] = sdd + d * d
            w[_SDG, j] = sdg + d * g
            w[_SDE, j] = sde + d * he
            w[_SEE, j] = see + he * he
            w[_SEG, j] = seg + he * g
            w[_H, j] = a * h + u3
            w[_HE, j] = a * he + e3
            w[_G, j] = ag * g + _G_FLOOR
        k += 4
    return k


@njit(nogil=True, cache=True, fastmath={"contract"})
def _fit_moments(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, st: int, en: int
) -> int:
    """:func:`_fit_hold` with three moments per interval."""
    width = w.shape[1]
    k = st
    while k + 4 <= en:
        y0, y1, y2, y3 = y[k], y[k + 1], y[k + 2], y[k + 3]
        p0, q0, z0 = mu[k, 0], mu[k, 1], mu[k, 2]
        p1, q1, z1 = mu[k + 1, 0], mu[k + 1, 1], mu[k + 1, 2]
        p2, q2, z2 = mu[k + 2, 0], mu[k + 2, 1], mu[k + 2, 2]
        p3, q3, z3 = mu[k + 3, 0], mu[k + 3, 1], mu[k + 3, 2]
        pe0, qe0, ze0 = mu_emf[k, 0], mu_emf[k, 1], mu_emf[k, 2]
        pe1, qe1, ze1 = mu_emf[k + 1, 0], mu_emf[k + 1, 1], mu_emf[k + 1, 2]
        pe2, qe2, ze2 = mu_emf[k + 2, 0], mu_emf[k + 2, 1], mu_emf[k + 2, 2]
        pe3, qe3, ze3 = mu_emf[k + 3, 0], mu_emf[k + 3, 1], mu_emf[k + 3, 2]
        for j in range(width):
            h = w[_H, j]
            he = w[_HE, j]
            g = w[_G, j]
            a = w[_A, j]
            c = w[_C0, j]
            ag = w[_AG, j]
            r1 = w[_R1, j]
            r2 = w[_R2, j]
            sdd = w[_SDD, j]
            sdg = w[_SDG, j]
            sde = w[_SDE, j]
            see = w[_SEE, j]
            seg = w[_SEG, j]
            d = y0 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + (p0 + r1 * q0 + r2 * z0)
            he = a * he + (pe0 + r1 * qe0 + r2 * ze0)
            g = ag * g + _G_FLOOR
            d = y1 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + (p1 + r1 * q1 + r2 * z1)
            he = a * he + (pe1 + r1 * qe1 + r2 * ze1)
            g = ag * g + _G_FLOOR
            d = y2 - c * h
            sdd += d * d
            sdg += d * g
            sde += d * he
            see += he * he
            seg += he * g
            h = a * h + (p2 + r1 * q2 + r2 * z2)
            he = a * he + (pe2 + r1 * qe2 + r2 * ze2)
            g = ag * g + _G_FLOOR
            d = y3 - c * h
            w[_SDD, j] = sdd + d * d
            w[_SDG, j] = sdg + d * g
            w[_SDE, j] = sde + d * he
            w[_SEE, j] = see + he * he
            w[_SEG, j] = seg + he * g
            w[_H, j] = a * h + (p3 + r1 * q3 + r2 * z3)
            w[_HE, j] = a * he + (pe3 + r1 * qe3 + r2 * ze3)
            w[_G, j] = ag * g + _G_FLOOR
        k += 4
    return k


@njit(nogil=True, cache=True, fastmath={"contract"})
def _fit_tail(
    w: np.ndarray, y: np.ndarray, mu: np.ndarray, mu_emf: np.ndarray, k0: int, en: int
) -> None:
    """Intervals ``k0 .. en-1`` one at a time (``K`` fitted), then the last sample ``en``."""
    width = w.shape[1]
    for k in range(k0, en):
        yk = y[k]
        p, q, z = mu[k, 0], mu[k, 1], mu[k, 2]
        pe, qe, ze = mu_emf[k, 0], mu_emf[k, 1], mu_emf[k, 2]
        for j in range(width):
            h = w[_H, j]
            he = w[_HE, j]
            g = w[_G, j]
            d = yk - w[_C0, j] * h
            w[_SDD, j] += d * d
            w[_SDG, j] += d * g
            w[_SDE, j] += d * he
            w[_SEE, j] += he * he
            w[_SEG, j] += he * g
            r1 = w[_R1, j]
            r2 = w[_R2, j]
            w[_H, j] = w[_A, j] * h + (p + r1 * q + r2 * z)
            w[_HE, j] = w[_A, j] * he + (pe + r1 * qe + r2 * ze)
            w[_G, j] = w[_AG, j] * g + _G_FLOOR
    yk = y[en]
    for j in range(width):
        he = w[_HE, j]
        g = w[_G, j]
        d = yk - w[_C0, j] * w[_H, j]
        w[_SDD, j] += d * d
        w[_SDG, j] += d * g
        w[_SDE, j] += d * he
        w[_SEE, j] += he * he
        w[_SEG, j] += he * g


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    log_scale: bool,
    emf_mode: int,
    emf_constant: float,
    input_noise_var: float,
    n_moments: int = 3,
) -> np.ndarray:
    """Eq. (1) for every particle, over segments, ``K`` and each segment's ``i0`` projected out.

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(R [ohm], L [H])`` per particle, or their base-10 logarithms.
    mu, mu_emf : (n - 1, 3) arrays
        Legendre moments of the winding voltage (V) and of ``if*omega``
        (A*rad/s) over each interval; ``mu_emf`` is ignored when
        ``emf_mode == EMF_NONE``.
    current : (n,) array
        Measured winding current (A).
    starts, ends : (n_segments,) int arrays
        First and last sample of each segment (inclusive; intervals between
        segments are skipped).
    emf_mode : {EMF_NONE, EMF_FIT, EMF_HELD}
    emf_constant : float
        ``K`` when ``emf_mode == EMF_HELD``.
    input_noise_var : float
        Variance (V^2) of white noise on the voltage whose expected share of
        the cost is subtracted (errors-in-variables compensation).
    n_moments : {3, 1}
        1: the voltage is held over each interval (only ``mu[:, 0]`` and
        ``mu_emf[:, 0]`` are read; the others must be 0), which saves two or
        four FMAs per particle and sample.

    Returns
    -------
    (n_particles,) array of sums of squared current error (A^2).

    Notes
    -----
    The same cost as :func:`plain_moment_swarm_costs`, to rounding. The swarm
    is laid out particle-major in one work array, padded to whole vectors of
    :data:`LANES` doubles, so the particle loop vectorises without remainder
    or aliasing checks, and the samples are taken four at a time so a
    particle's state stays in registers between its loads and stores. The
    forced responses are kept divided by ``c_0``, which saves a product per
    sample. ``python -m bench.kernel_speed`` measures it against the FMA peak.
    """
    n_particles = positions.shape[0]
    width = ((n_particles + LANES - 1) // LANES) * LANES
    w = np.empty((_ROWS, width))
    for j in range(width):
        p = min(j, n_particles - 1)
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a, c0, c1, c2 = moment_coefficients(r, ell, dt)
        w[_A, j] = a
        w[_C0, j] = c0
        w[_AG, j] = max(a, _A_FLOOR)
        w[_R1, j] = c1 / c0
        w[_R2, j] = c2 / c0
    fit_k = emf_mode == EMF_FIT
    held = emf_mode == EMF_HELD
    k_held = emf_constant if held else 0.0
    big_a = np.zeros(width)
    big_b = np.zeros(width)
    big_c = np.zeros(width)
    noise = np.zeros(width)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        for j in range(width):
            w[_H, j] = 0.0
            w[_HE, j] = 0.0
            w[_G, j] = 1.0
            w[_SDD, j] = 0.0
            w[_SDG, j] = 0.0
            w[_SDE, j] = 0.0
            w[_SEE, j] = 0.0
            w[_SEG, j] = 0.0
        if fit_k:
            if n_moments == 1:
                k = _fit_hold(w, current, mu, mu_emf, st, en)
            else:
                k = _fit_moments(w, current, mu, mu_emf, st, en)
            _fit_tail(w, current, mu, mu_emf, k, en)
        else:
            if n_moments == 1:
                k = _plain_hold(w, current, mu, mu_emf, held, k_held, st, en)
            else:
                k = _plain_moments(w, current, mu, mu_emf, held, k_held, st, en)
            _plain_tail(w, current, mu, mu_emf, held, k_held, k, en)
        m_seg = en - st + 1
        for j in range(width):
            a = w[_A, j]
            c0 = w[_C0, j]
            s_gg = geometric_energy(a, m_seg)
            s_dg = w[_SDG, j]
            big_a[j] += w[_SDD, j] - s_dg * s_dg / s_gg
            if fit_k:
                s_eg = c0 * w[_SEG, j]
                big_b[j] += c0 * w[_SDE, j] - s_dg * s_eg / s_gg
                big_c[j] += c0 * c0 * w[_SEE, j] - s_eg * s_eg / s_gg
            if input_noise_var > 0.0:
                noise[j] += segment_noise_energy(a, c0, m_seg)
    out = np.empty(n_particles)
    for p in range(n_particles):
        cost = big_a[p]
        if fit_k and big_c[p] > _SINGULAR_RTOL * abs(big_a[p]) + 1e-300:
            cost -= big_b[p] * big_b[p] / big_c[p]
        out[p] = cost - input_noise_var * noise[p]
    return out


@njit(nogil=True, cache=True, fastmath={"contract"})
def moment_residual(
    resistance: float,
    inductance: float,
    emf_constant: float,
    mu: np.ndarray,
    mu_emf: np.ndarray,
    current: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    dt: float,
    has_emf: bool,
    out: np.ndarray,
    initial: np.ndarray,
) -> None:
    """Current residual (A) of every segment's sample, each segment's ``i0`` projected out.

    ``out`` receives the residuals of the segments' samples one after another
    (its length is the number of samples in segments); ``initial`` receives
    each segment's fitted initial current (A).

    The recursion is latency-bound: the interval's input is summed apart, so
    one FMA (not four dependent operations) separates ``f[k+1]`` from ``f[k]``,
    and the free response is kept from the first pass for the second.
    """
    a, c0, c1, c2 = moment_coefficients(resistance, inductance, dt)
    a_g = max(a, _A_FLOOR)
    longest = 0
    for s in range(starts.shape[0]):
        longest = max(longest, ends[s] - starts[s] + 1)
    free = np.empty(longest)
    pos = 0
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        f = 0.0
        g = 1.0
        s_dg = 0.0
        s_gg = 0.0
        for k in range(st, en):
            d = current[k] - f
            out[pos + k - st] = d
            free[k - st] = g
            s_dg += d * g
            s_gg += g * g
            if has_emf:
                u = (
                    c0 * (mu[k, 0] - emf_constant * mu_emf[k, 0])
                    + c1 * (mu[k, 1] - emf_constant * mu_emf[k, 1])
                    + c2 * (mu[k, 2] - emf_constant * mu_emf[k, 2])
                )
            else:
                u = c0 * mu[k, 0] + c1 * mu[k, 1] + c2 * mu[k, 2]
            f = a * f + u
            g = a_g * g + _G_FLOOR
        d = current[en] - f
        out[pos + en - st] = d
        free[en - st] = g
        s_dg += d * g
        s_gg += g * g
        i0 = s_dg / s_gg
        initial[s] = i0
        m = en - st + 1
        for i in range(m):
            out[pos + i] -= i0 * free[i]
        pos += m


# ---------------------------------------------------------------- reconstruction

#: Gauss-Legendre nodes on [0, 1] used to take moments of a reconstructed voltage.
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(6)
GAUSS_U = 0.5 * (_GAUSS_X + 1.0)
GAUSS_W = 0.5 * _GAUSS_W


@njit(nogil=True, cache=True)
def _cubic_point(v: np.ndarray, st: int, m: int, npts: int, x: float) -> float:
    """The segment's cubic (``npts`` samples nearest ``x``, all inside) at ``x`` (periods)."""
    lo = int(math.floor(x)) - 1
    if lo < 0:
        lo = 0
    if lo > m - npts:
        lo = m - npts
    val = 0.0
    for ia in range(npts):
        la = 1.0
        for ib in range(npts):
            if ib != ia:
                la *= (x - (lo + ib)) / (ia - ib)
        val += la * v[st + lo + ia]
    return val


@njit(nogil=True, cache=True)
def interpolated_moments(
    v: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    shift: float,
    gauss_u: np.ndarray,
    gauss_w: np.ndarray,
    out: np.ndarray,
) -> None:
    """Legendre moments of a piecewise-cubic reconstruction of sampled ``v``, per interval.

    Within each segment the voltage is the cubic (Lagrange) through the four
    samples nearest the point, all inside the segment (one-sided at its
    ends), evaluated ``shift`` sample periods later (a relative delay between
    the voltage and current channels; > 0: the voltage is read later).
    Intervals outside segments are left as they are in ``out``.

    Away from a segment's ends every interval sees the same cubic weights (they
    depend on ``shift`` only), so its moments are one fixed stencil of at most
    five samples, computed once per call; only the few intervals near the ends,
    where the cubic turns one-sided, evaluate it point by point.
    """
    n_nodes = gauss_u.shape[0]
    # Nodes lie inside (0, 1): their floors after the shift differ by at most one.
    base = int(math.floor(gauss_u[0] + shift))
    for gi in range(n_nodes):
        base = min(base, int(math.floor(gauss_u[gi] + shift)))
    # stencil[j, t]: weight of sample (k + base - 1 + t) in moment j of interval k.
    stencil = np.zeros((3, 5))
    top = base
    for gi in range(n_nodes):
        u = gauss_u[gi]
        o = int(math.floor(u + shift))
        top = max(top, o)
        frac = u + shift - o  # the node's position after sample k + o
        legendre = (1.0, 2.0 * u - 1.0, 6.0 * u * u - 6.0 * u + 1.0)
        for ia in range(4):
            la = 1.0
            for ib in range(4):
                if ib != ia:
                    la *= (frac + 1.0 - ib) / (ia - ib)
            for j in range(3):
                stencil[j, o - base + ia] += gauss_w[gi] * legendre[j] * la
    taps = top - base + 4
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        m = en - st + 1
        npts = 4 if m >= 4 else m
        for k in range(m - 1):
            first = k + base - 1
            if npts == 4 and first >= 0 and k + top - 1 <= m - 4:
                q0 = 0.0
                q1 = 0.0
                q2 = 0.0
                for t in range(taps):
                    x = v[st + first + t]
                    q0 += stencil[0, t] * x
                    q1 += stencil[1, t] * x
                    q2 += stencil[2, t] * x
            else:
                q0 = 0.0
                q1 = 0.0
                q2 = 0.0
                for gi in range(n_nodes):
                    u = gauss_u[gi]
                    wv = gauss_w[gi] * _cubic_point(v, st, m, npts, k + u + shift)
                    q0 += wv
                    q1 += wv * (2.0 * u - 1.0)
                    q2 += wv * (6.0 * u * u - 6.0 * u + 1.0)
            out[st + k, 0] = q0
            out[st + k, 1] = q1
            out[st + k, 2] = q2


@njit(nogil=True, cache=True)
def lowpass_segments(
    x: np.ndarray, lengths: np.ndarray, b: np.ndarray, a: np.ndarray, out: np.ndarray
) -> None:
    """A biquad ``(b, a)`` over each segment of ``x`` (``lengths`` in order), restarted."""
    pos = 0
    for s in range(lengths.shape[0]):
        m = lengths[s]
        x1 = 0.0
        x2 = 0.0
        y1 = 0.0
        y2 = 0.0
        for k in range(m):
            xi = x[pos + k]
            yi = b[0] * xi + b[1] * x1 + b[2] * x2 - a[1] * y1 - a[2] * y2
            out[pos + k] = yi
            x2 = x1
            x1 = xi
            y2 = y1
            y1 = yi
        pos += m


@njit(nogil=True, cache=True)
def lag_samples(
    mu: np.ndarray, v: np.ndarray, starts: np.ndarray, ends: np.ndarray, lag: float, out: np.ndarray
) -> None:
    """Samples of ``v`` through a first-order lag of ``lag`` sample periods, exactly per interval.

    ``mu`` holds the moments of ``v`` over each interval (its reconstruction
    between samples); each segment starts from rest at its first sample.
    """
    a, c0, c1, c2 = moment_coefficients(1.0, lag, 1.0)
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        x = v[st]
        out[st] = x
        for k in range(st, en):
            x = a * x + c0 * mu[k, 0] + c1 * mu[k, 1] + c2 * mu[k, 2]
            out[k + 1] = x
