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


@njit(nogil=True, cache=True)
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
    """
    a, c0, c1, c2 = moment_coefficients(resistance, inductance, dt)
    pos = 0
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        f = 0.0
        g = 1.0
        s_dg = 0.0
        s_gg = 0.0
        for k in range(st, en + 1):
            d = current[k] - f
            out[pos + k - st] = d
            s_dg += d * g
            s_gg += g * g
            if k < en:
                u0 = mu[k, 0]
                u1 = mu[k, 1]
                u2 = mu[k, 2]
                if has_emf:
                    u0 -= emf_constant * mu_emf[k, 0]
                    u1 -= emf_constant * mu_emf[k, 1]
                    u2 -= emf_constant * mu_emf[k, 2]
                f = a * f + c0 * u0 + c1 * u1 + c2 * u2
                g = max(a, _A_FLOOR) * g + _G_FLOOR
        i0 = s_dg / s_gg
        initial[s] = i0
        g = 1.0
        for k in range(st, en + 1):
            out[pos + k - st] -= i0 * g
            g = max(a, _A_FLOOR) * g + _G_FLOOR
        pos += en - st + 1


# ---------------------------------------------------------------- reconstruction

#: Gauss-Legendre nodes on [0, 1] used to take moments of a reconstructed voltage.
_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(6)
GAUSS_U = 0.5 * (_GAUSS_X + 1.0)
GAUSS_W = 0.5 * _GAUSS_W


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
    """
    for s in range(starts.shape[0]):
        st = starts[s]
        en = ends[s]
        m = en - st + 1
        npts = 4 if m >= 4 else m
        for k in range(m - 1):
            q0 = 0.0
            q1 = 0.0
            q2 = 0.0
            for gi in range(gauss_u.shape[0]):
                u = gauss_u[gi]
                x = k + u + shift
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
                wv = gauss_w[gi] * val
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
