"""Numba kernels: exact discretisation of the winding models and swarm costs.

Everything here is a pure function over arrays, compiled with
``@njit(nogil=True, cache=True)`` so that the observer thread releases the GIL
while it estimates and acquisition never stalls. The Python objects that drive
these kernels live in :mod:`observer.estimation.pso`, :mod:`observer.estimation.field`
and :mod:`observer.estimation.armature`.
The simulated plant's kernels are apart, in :mod:`observer.simulation.kernels`:
they simulate a drive, they do not estimate.

Discretisation
--------------
A winding is a first-order RL circuit ``v = R*i + L*di/dt``. With the voltage
held constant over each sample period ``dt`` (zero-order hold, what a digital
drive that samples synchronously with its modulator applies) the exact discrete
model is::

    i[k+1] = a*i[k] + b*v[k],   a = exp(-R*dt/L),   b = (1 - a)/R

so estimates do not depend on the sample rate, unlike forward Euler.

For the armature, ``v = va - K*if*omega``. The back-EMF is a state, not a held
input; over one period it is replaced by the mean of its two end-point values
(trapezoidal hold), which is exact to second order in ``dt / tau_mech``.

Separable least squares
-----------------------
The simulated current is linear in the initial current ``i0`` and, for the
armature, in the EMF constant ``K``::

    i_sim = f_v(R, L) - K*f_e(R, L) + i0*a^k

so for every particle (R, L) these linear parameters are solved in closed form
(variable projection, Golub & Pereyra 1973) and the swarm searches only the
two nonlinear ones. The cost stays the paper's eq. (1): the sum of squared
differences between measured and simulated winding current.

Swarm layout
------------
Costs are computed for a whole swarm in one call, ``(n_particles, n_params) ->
(n_particles,)``. The loop runs over samples outside and particles inside, so
the particle loop has no dependency chain and vectorises (SIMD) while the
recursion over samples proceeds in lock-step for all particles.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Below this Gram determinant (relative), K is not identifiable from the window.
_SINGULAR_RTOL = 1e-10

#: The free response ``a^k`` of the swarm kernels is kept above this floor:
#: ``g <- a*g + _G_FLOOR`` with ``a >= _A_FLOOR``. Letting it decay through the
#: subnormal range costs ~100 cycles per operation (measured: a 4x slower swarm
#: cost for mid-range ``a``); the floor keeps every product normal without a
#: compare-and-select per sample, and changes ``g`` by less than
#: ``n * _G_FLOOR`` (1e-196 on 10^4 samples), far below rounding.
_G_FLOOR = 1e-200
_A_FLOOR = 1e-100


@njit(nogil=True, cache=True)
def geometric_energy(a: float, n: int) -> float:
    """``sum_{k<n} a^(2k)``, the energy of the free response to a unit initial current."""
    aa = a * a
    if aa < 1.0:
        return (1.0 - aa**n) / (1.0 - aa)
    return float(n)


@njit(nogil=True, cache=True)
def zoh_coefficients(resistance: float, inductance: float, dt: float) -> tuple[float, float]:
    """Exact ZOH coefficients ``(a, b)`` of ``v = R i + L di/dt`` for period ``dt``."""
    a = np.exp(-resistance * dt / inductance)
    return a, (1.0 - a) / resistance


@njit(nogil=True, cache=True)
def input_noise_energy(a: float, b: float, n: int) -> float:
    """Expected sum of squares, over ``n`` samples, of unit white input noise through the model.

    Noise on a measured input voltage reaches the simulated current through the
    impulse response ``h_j = b*a^j``, adding ``sum_k sum_{j<k} h_j^2`` per unit
    variance to eq. (1). That term grows with the model's gain, so output error
    with noisy inputs is biased (errors-in-variables); subtracting it removes
    the bias in expectation.
    """
    aa = a * a
    if aa >= 1.0:
        return b * b * n * (n - 1) / 2.0
    return b * b / (1.0 - aa) * (n - geometric_energy(a, n))


@njit(nogil=True, cache=True)
def emf_input(if_a: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Per-period mean of ``if*omega`` (trapezoid of the two end points), A*rad/s."""
    n = if_a.shape[0]
    e = np.empty(n)
    for k in range(n - 1):
        e[k] = 0.5 * (if_a[k] * omega[k] + if_a[k + 1] * omega[k + 1])
    if n > 0:
        e[n - 1] = if_a[n - 1] * omega[n - 1]
    return e


@njit(nogil=True, cache=True)
def simulate_rl(
    resistance: float, inductance: float, i0: float, voltage: np.ndarray, dt: float
) -> np.ndarray:
    """Current of an RL winding driven by the held ``voltage`` samples (A)."""
    a, b = zoh_coefficients(resistance, inductance, dt)
    n = voltage.shape[0]
    out = np.empty(n)
    i = i0
    for k in range(n):
        out[k] = i
        i = a * i + b * voltage[k]
    return out


@njit(nogil=True, cache=True)
def simulate_armature(
    resistance: float,
    inductance: float,
    emf_constant: float,
    i0: float,
    va: np.ndarray,
    emf: np.ndarray,
    dt: float,
) -> np.ndarray:
    """Armature current for held ``va`` and per-period ``emf = mean(if*omega)`` (A)."""
    a, b = zoh_coefficients(resistance, inductance, dt)
    n = va.shape[0]
    out = np.empty(n)
    i = i0
    for k in range(n):
        out[k] = i
        i = a * i + b * (va[k] - emf_constant * emf[k])
    return out


@njit(nogil=True, cache=True, fastmath={"contract"})
def rl_swarm_costs(
    positions: np.ndarray,
    voltage: np.ndarray,
    current: np.ndarray,
    dt: float,
    log_scale: bool,
    input_noise_var: float = 0.0,
) -> np.ndarray:
    """Eq. (1) for every particle of an RL winding, initial current projected out.

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(R [ohm], L [H])`` per particle, or their base-10 logarithms if ``log_scale``.
    voltage, current : (n_samples,) arrays
        Measured winding voltage (V) and current (A).
    dt : float
        Sample period (s).
    input_noise_var : float
        Variance of white noise on the model's input voltage (V^2). Its
        expected contribution to the cost, which grows with the model's gain
        and so biases the estimate, is subtracted (see :func:`input_noise_energy`).

    Returns
    -------
    (n_particles,) array of sums of squared current error (A^2).

    Notes
    -----
    The sample loop is unrolled by two: each particle's state is loaded and
    stored once per pair of samples. The loop is limited by loads and stores,
    not arithmetic, so this halves its time (measured: 100 -> 60 us for 100
    particles on 2000 samples). Only FMA contraction is allowed (no
    reassociation, NaN semantics kept).
    """
    n_particles = positions.shape[0]
    n = voltage.shape[0]
    a = np.empty(n_particles)
    b = np.empty(n_particles)
    a_g = np.empty(n_particles)  # decay of the floored free response
    f = np.zeros(n_particles)  # forced response from zero initial current
    g = np.ones(n_particles)  # free response a^k to unit initial current
    s_dd = np.zeros(n_particles)
    s_dg = np.zeros(n_particles)
    for p in range(n_particles):
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a[p] = np.exp(-r * dt / ell)
        b[p] = (1.0 - a[p]) / r
        a_g[p] = max(a[p], _A_FLOOR)
    even = n - n % 2
    for k in range(0, even, 2):
        y0 = current[k]
        v0 = voltage[k]
        y1 = current[k + 1]
        v1 = voltage[k + 1]
        for p in range(n_particles):
            ap = a[p]
            bp = b[p]
            agp = a_g[p]
            g0 = g[p]
            d0 = y0 - f[p]
            f1 = ap * f[p] + bp * v0
            g1 = agp * g0 + _G_FLOOR
            d1 = y1 - f1
            f[p] = ap * f1 + bp * v1
            g[p] = agp * g1 + _G_FLOOR
            s_dd[p] += d0 * d0 + d1 * d1
            s_dg[p] += d0 * g0 + d1 * g1
    for k in range(even, n):
        y = current[k]
        v = voltage[k]
        for p in range(n_particles):
            d = y - f[p]
            s_dd[p] += d * d
            s_dg[p] += d * g[p]
            f[p] = a[p] * f[p] + b[p] * v
            g[p] = a_g[p] * g[p] + _G_FLOOR
    out = np.empty(n_particles)
    for p in range(n_particles):
        out[p] = s_dd[p] - s_dg[p] * s_dg[p] / geometric_energy(a[p], n)
        if input_noise_var > 0.0:
            out[p] -= input_noise_var * input_noise_energy(a[p], b[p], n)
    return out


@njit(nogil=True, cache=True, fastmath={"contract"})
def armature_swarm_costs(
    positions: np.ndarray,
    va: np.ndarray,
    emf: np.ndarray,
    current: np.ndarray,
    dt: float,
    log_scale: bool,
    emf_constant: float,
    input_noise_var: float = 0.0,
) -> np.ndarray:
    """Eq. (1) for every particle of the armature, ``K`` and ``i0`` projected out.

    Parameters
    ----------
    positions : (n_particles, 2) array
        ``(Ra [ohm], La [H])`` per particle, or their base-10 logarithms.
    va, emf, current : (n_samples,) arrays
        Armature voltage (V), per-period ``mean(if*omega)`` (A*rad/s, see
        :func:`emf_input`) and measured armature current (A).
    emf_constant : float
        ``NaN`` to fit ``K`` by projection; a number to hold ``K`` at that value
        (a window without speed, where ``K`` is not identifiable).
    input_noise_var : float
        Variance of white noise on ``va - K*emf`` (V^2), compensated as in
        :func:`rl_swarm_costs`.
    """
    n_particles = positions.shape[0]
    n = va.shape[0]
    fit_k = np.isnan(emf_constant)
    k_fixed = 0.0 if fit_k else emf_constant
    a = np.empty(n_particles)
    b = np.empty(n_particles)
    fv = np.zeros(n_particles)  # response to va (or va - K*emf if K is held)
    fe = np.zeros(n_particles)  # response to emf
    g = np.ones(n_particles)
    s_dd = np.zeros(n_particles)
    s_ee = np.zeros(n_particles)
    s_de = np.zeros(n_particles)
    s_dg = np.zeros(n_particles)
    s_eg = np.zeros(n_particles)
    a_g = np.empty(n_particles)
    for p in range(n_particles):
        r = positions[p, 0]
        ell = positions[p, 1]
        if log_scale:
            r = 10.0**r
            ell = 10.0**ell
        a[p] = np.exp(-r * dt / ell)
        b[p] = (1.0 - a[p]) / r
        a_g[p] = max(a[p], _A_FLOOR)
    # Unrolled by two samples, as in rl_swarm_costs.
    even = n - n % 2
    for k in range(0, even, 2):
        y0 = current[k]
        u0 = va[k] - k_fixed * emf[k]
        e0 = emf[k]
        y1 = current[k + 1]
        u1 = va[k + 1] - k_fixed * emf[k + 1]
        e1 = emf[k + 1]
        for p in range(n_particles):
            ap = a[p]
            bp = b[p]
            agp = a_g[p]
            g0 = g[p]
            fe0 = fe[p]
            d0 = y0 - fv[p]
            fv1 = ap * fv[p] + bp * u0
            fe1 = ap * fe0 + bp * e0
            g1 = agp * g0 + _G_FLOOR
            d1 = y1 - fv1
            fv[p] = ap * fv1 + bp * u1
            fe[p] = ap * fe1 + bp * e1
            g[p] = agp * g1 + _G_FLOOR
            s_dd[p] += d0 * d0 + d1 * d1
            s_ee[p] += fe0 * fe0 + fe1 * fe1
            s_de[p] += d0 * fe0 + d1 * fe1
            s_dg[p] += d0 * g0 + d1 * g1
            s_eg[p] += fe0 * g0 + fe1 * g1
    for k in range(even, n):
        y = current[k]
        u = va[k] - k_fixed * emf[k]
        e = emf[k]
        for p in range(n_particles):
            d = y - fv[p]
            s_dd[p] += d * d
            s_ee[p] += fe[p] * fe[p]
            s_de[p] += d * fe[p]
            s_dg[p] += d * g[p]
            s_eg[p] += fe[p] * g[p]
            fv[p] = a[p] * fv[p] + b[p] * u
            fe[p] = a[p] * fe[p] + b[p] * e
            g[p] = a_g[p] * g[p] + _G_FLOOR
    out = np.empty(n_particles)
    for p in range(n_particles):
        s_gg = geometric_energy(a[p], n)
        # d ~= -K*fe + i0*g: normal equations in (K, i0), residual by projection.
        det = s_ee[p] * s_gg - s_eg[p] * s_eg[p]
        if fit_k and det > _SINGULAR_RTOL * s_ee[p] * s_gg:
            kk = (-s_de[p] * s_gg + s_eg[p] * s_dg[p]) / det
            i0 = (s_dg[p] * s_ee[p] - s_de[p] * s_eg[p]) / det
            out[p] = s_dd[p] + kk * s_de[p] - i0 * s_dg[p]
        else:
            out[p] = s_dd[p] - s_dg[p] * s_dg[p] / s_gg
        if input_noise_var > 0.0:
            out[p] -= input_noise_var * input_noise_energy(a[p], b[p], n)
    return out


@njit(nogil=True, cache=True)
def pso_update(
    x: np.ndarray,
    v: np.ndarray,
    personal_best: np.ndarray,
    global_best: np.ndarray,
    r1: np.ndarray,
    r2: np.ndarray,
    w: float,
    c1: float,
    c2: float,
    lower: np.ndarray,
    upper: np.ndarray,
    v_max: np.ndarray,
) -> None:
    """One step of the paper's eq. (2), in place, with velocity clamp and bounds.

    ``V <- w V + c1 r1 (pb - X) + c2 r2 (gb - X)``; ``X <- X + V``. A particle
    that would leave the box is put on the wall and its velocity component
    reversed and damped (a reflecting wall keeps the swarm's diversity, unlike
    absorbing walls that pile particles on the boundary).
    """
    n, d = x.shape
    for p in range(n):
        for j in range(d):
            vel = (
                w * v[p, j]
                + c1 * r1[p, j] * (personal_best[p, j] - x[p, j])
                + c2 * r2[p, j] * (global_best[j] - x[p, j])
            )
            if vel > v_max[j]:
                vel = v_max[j]
            elif vel < -v_max[j]:
                vel = -v_max[j]
            pos = x[p, j] + vel
            if pos < lower[j]:
                pos = lower[j]
                vel = -0.5 * vel
            elif pos > upper[j]:
                pos = upper[j]
                vel = -0.5 * vel
            x[p, j] = pos
            v[p, j] = vel


@njit(nogil=True, cache=True)
def update_personal_best(
    x: np.ndarray, cost: np.ndarray, personal_best: np.ndarray, personal_cost: np.ndarray
) -> int:
    """Keep each particle's best position; return the index of the swarm's best."""
    n, d = x.shape
    best = 0
    for p in range(n):
        c = cost[p]
        if c < personal_cost[p]:  # NaN costs never win
            personal_cost[p] = c
            for j in range(d):
                personal_best[p, j] = x[p, j]
        if personal_cost[p] < personal_cost[best]:
            best = p
    return best


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def score_products(
    jac: np.ndarray, residual: np.ndarray, batch: int
) -> tuple[np.ndarray, np.ndarray]:
    """``J'J``, and ``sum s s'`` over the score sums ``s = sum J_k r_k`` of every run of ``batch``.

    The sandwich bound's two products
    (:func:`observer.estimation.uncertainty.crlb_std`) column by column: every
    run of ``batch`` consecutive samples counted once, its sums sliding (one
    sample in, one out); ``batch = 0``: no runs, the second product is zero.
    The sums of products may be reassociated (vectorised).
    """
    n, p = jac.shape
    cols = np.empty((p, n))
    for k in range(n):
        for i in range(p):
            cols[i, k] = jac[k, i]
    jtj = _gram(cols)
    if batch < 1 or batch > n:
        return jtj, np.zeros((p, p))
    rows = n + 1 - batch
    sums = np.empty((p, rows))
    for i in range(p):
        s = 0.0
        for k in range(batch):
            s += cols[i, k] * residual[k]
        sums[i, 0] = s
        for k in range(batch, n):
            s += cols[i, k] * residual[k] - cols[i, k - batch] * residual[k - batch]
            sums[i, k - batch + 1] = s
    return jtj, _gram(sums)


@njit(nogil=True, cache=True, fastmath={"reassoc", "contract"})
def _gram(rows: np.ndarray) -> np.ndarray:
    """``X X'`` of a ``(p, m)`` array: the products of its rows (reassociated sums)."""
    p, m = rows.shape
    out = np.empty((p, p))
    for i in range(p):
        for j in range(i + 1):
            acc = 0.0
            for k in range(m):
                acc += rows[i, k] * rows[j, k]
            out[i, j] = acc
            out[j, i] = acc
    return out


@njit(nogil=True, cache=True)
def autocovariances(x: np.ndarray, max_lag: int) -> np.ndarray:
    """``sum_k x[k] x[k+lag] / n`` for ``lag = 1 .. max_lag`` (``x`` already centred).

    The lags are the inner loop: independent sums that vectorise, where one
    dot product per lag is a chain of dependent additions.
    """
    n = x.shape[0]
    out = np.zeros(max_lag)
    for k in range(n - 1):
        xk = x[k]
        top = min(max_lag, n - 1 - k)
        for lag in range(top):
            out[lag] += xk * x[k + 1 + lag]
    return out / n
