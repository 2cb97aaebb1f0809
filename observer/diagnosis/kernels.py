"""Numba kernels of the extended winding models the diagnosis fits.

One physical parameter vector, laid out as :data:`FULL_PARAMS`, describes the
plain model plus every candidate effect; an effect that is absent sits at its
neutral value (zero). The kernels simulate the measured field and armature
currents over a set of segments of the recording (each segment restarts the
simulation, so a model can be fitted on some segments and scored on others),
and return the residual. Linear parameters are projected out as in
:mod:`observer.estimation.kernels`: the armature's ``K`` (shared by all segments) and its
initial current (one per segment).

Model (per sample period ``dt``; ``P`` the copper loss at the baseline (cold)
resistances, so ``P*(1+theta)`` is the loss the hot windings dissipate)::

    theta:  theta[k+1] = theta[k] + (1 - exp(-dt/tau_th)) * (k_th*P[k]*(1+theta[k]) - theta[k])
    field:  Lf/(1+c|if|)^2 * dif/dt = vf - Rf*(1+theta)*if  (+ eddy path: k2, tau_e)
    arm.:   La*dia/dt = va - Ra*(1+theta)*ia - Vb*tanh(ia/iw)
                        - K*g(if)*(1 - beta*|ia|)*omega,   g(if) = if/(1+c|if|)
    sensors: measured current = model current at t - skew, + offset (skew < 0: the
             current channels sampled after the voltages, |skew| < 2 periods)

The winding voltages enter as their Legendre moments over every sample
interval (``mu``, ``(n - 1, 3)``), the estimator's intersample model
(:mod:`observer.estimation.intersample`: ``hold`` is ``(v[k], 0, 0)``, which
makes these the zero-order-hold kernels; ``smooth``, ``switched`` and
``averaged`` describe a voltage that varies between samples, as a
converter's does). The exact update of a first-order winding over a period is
then :func:`~observer.estimation.intersample_kernels.moment_coefficients`'.
The field is advanced with its local linearisation held over the period
(exact for the plain model, second order in ``dt/tau`` otherwise); the eddy
path makes the field a two-state linear system, advanced by its exact 2x2
matrix exponential with the interval's mean voltage.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from observer.estimation.intersample_kernels import moment_coefficients

#: Names of the entries of the full parameter vector, with units.
FULL_PARAMS = (
    "Rf",  # ohm
    "Lf",  # H
    "Ra",  # ohm
    "La",  # H
    "saturation_per_a",  # 1/A
    "thermal_rise_per_w",  # 1/W
    "thermal_time_constant_s",  # s
    "brush_drop_v",  # V
    "reaction_per_a",  # 1/A
    "eddy_coupling",  # -
    "eddy_time_constant_s",  # s
    "if_offset_a",  # A
    "ia_offset_a",  # A
    "current_delay_s",  # s
)
N_FULL = len(FULL_PARAMS)
(
    I_RF, I_LF, I_RA, I_LA, I_SAT, I_KTH, I_TTH, I_VB, I_BETA, I_K2, I_TE, I_OFF_IF, I_OFF_IA,
    I_SKEW,
) = range(N_FULL)  # fmt: skip


@njit(nogil=True, cache=True)
def _coefficients(r: float, ell: float, dt: float, held: bool) -> tuple[float, float, float, float]:
    """``(a, c0, c1, c2)`` of a period; a held voltage's by the zero-order hold's formula."""
    if held:
        a = math.exp(-r * dt / ell)
        return a, (1.0 - a) / r, 0.0, 0.0
    return moment_coefficients(r, ell, dt)


@njit(nogil=True, cache=True)
def thermal_state(p: np.ndarray, loss: np.ndarray, dt: float, out: np.ndarray) -> None:
    """Relative resistance rise ``theta`` at every sample, from a cold start.

    ``loss`` is the copper loss at the cold resistances (W); the windings heat by
    the loss at the present ones, ``loss*(1 + theta)``.
    """
    kth = p[I_KTH]
    n = loss.shape[0]
    if kth == 0.0:
        for k in range(n):
            out[k] = 0.0
        return
    alpha = 1.0 - math.exp(-dt / p[I_TTH])
    th = 0.0
    for k in range(n):
        out[k] = th
        th += alpha * (kth * loss[k] * (1.0 + th) - th)


@njit(nogil=True, cache=True)
def _eddy_step(
    r: float, ell: float, k2: float, te: float, dt: float
) -> tuple[float, float, float, float, float, float]:
    """Exact ZOH step of the field with a coupled eddy path: ``Phi`` (2x2) and ``Gamma`` (2)."""
    m = 1.0 - k2
    a00 = -r / (ell * m)
    a01 = 1.0 / (te * m)
    a10 = k2 * r / (ell * m)
    a11 = -1.0 / te - k2 / (te * m)
    b0 = 1.0 / (ell * m)
    b1 = -k2 / (ell * m)
    s = 0.5 * (a00 + a11)
    det = a00 * a11 - a01 * a10
    q = math.sqrt(max(s * s - det, 0.0))
    e1 = math.exp((s + q) * dt)
    e2 = math.exp((s - q) * dt)
    ch = 0.5 * (e1 + e2)
    sh = 0.5 * (e1 - e2) / q if q > 1e-12 else dt * math.exp(s * dt)
    p00 = ch + sh * (a00 - s)
    p01 = sh * a01
    p10 = sh * a10
    p11 = ch + sh * (a11 - s)
    # Gamma = A^-1 (Phi - I) B
    c0 = (p00 - 1.0) * b0 + p01 * b1
    c1 = p10 * b0 + (p11 - 1.0) * b1
    g0 = (a11 * c0 - a01 * c1) / det
    g1 = (-a10 * c0 + a00 * c1) / det
    return p00, p01, p10, p11, g0, g1


@njit(nogil=True, cache=True)
def _skewed_end(k1: int, m_skew: int, n: int) -> int:
    """Where a segment ending at ``k1`` stops being simulated: a current read ``-m_skew``
    periods after its voltage is answered by the model's state that many samples later."""
    return min(k1 - m_skew, n) if m_skew < 0 else k1


@njit(nogil=True, cache=True)
def _advanced(x: np.ndarray, k: int, m: int, f: float) -> float:
    """``x`` at sample ``k + m + f`` (linear interpolation, clamped to the record)."""
    n = x.shape[0]
    i0 = min(max(k + m, 0), n - 1)
    i1 = min(max(k + m + 1, 0), n - 1)
    return (1.0 - f) * x[i0] + f * x[i1]


@njit(nogil=True, cache=True)
def field_residual(
    p: np.ndarray,
    mu: np.ndarray,
    if_m: np.ndarray,
    loss: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    dt: float,
    theta: np.ndarray,
    out: np.ndarray,
    held: bool = True,
) -> float:
    """Field-current residual ``if_measured - if_model`` over the segments; returns its SSE.

    ``mu`` (n - 1, 3) are the field voltage's moments per interval; ``out`` (n,)
    receives the residual at the segments' samples (others untouched); ``held``:
    the voltage is held (``mu``'s higher moments are zero), advanced as before
    intersample models, to the last bit;
    ``theta`` (n,) is work space.
    """
    rf0, lf, c = p[I_RF], p[I_LF], p[I_SAT]
    k2, te, off, skew = p[I_K2], p[I_TE], p[I_OFF_IF], p[I_SKEW]
    thermal_state(p, loss, dt, theta)
    thermal = p[I_KTH] != 0.0
    varying = thermal or c != 0.0
    m_skew = int(math.floor(skew / dt))
    f_skew = skew / dt - m_skew
    lead = min(m_skew, 0)  # a current read after its voltage: answered |lead| samples later
    a, c0, c1, c2 = _coefficients(rf0, lf, dt, held)
    n_int = mu.shape[0]
    p00 = p01 = p10 = p11 = g0 = g1 = 0.0
    if k2 > 0.0:
        p00, p01, p10, p11, g0, g1 = _eddy_step(rf0, lf, k2, te, dt)
    sens = np.empty(if_m.shape[0])
    sse = 0.0
    for s in range(starts.shape[0]):
        k0, k1 = starts[s], stops[s]
        # The eddy current is not measured: start earlier so that its unknown
        # initial value has decayed (5 eddy time constants) by the segment.
        kw = max(0, k0 - int(5.0 * te / dt)) if k2 > 0.0 else k0
        i = if_m[kw] - off
        if k1 - kw >= 3:
            i = (if_m[kw] + if_m[kw + 1] + if_m[kw + 2]) / 3.0 - off
        j = 0.0
        # Sensitivity of the current (and eddy current) to the initial current:
        # the initial current is projected out per segment (one Gauss-Newton
        # step, exact for the linear models), so that no model gains from the
        # noise of the measured starting value.
        si = 1.0
        sj = 0.0
        y0 = y1 = y2 = i + off  # model outputs at k, k-1, k-2
        s_rs = 0.0
        s_ss = 0.0
        s_rr = 0.0
        k_end = _skewed_end(k1, m_skew, if_m.shape[0])
        for k in range(kw, k_end):
            y2 = y1
            y1 = y0
            y0 = i + off
            if m_skew <= 0:
                ym = (1.0 - f_skew) * y0 + f_skew * y1
            else:
                ym = (1.0 - f_skew) * y1 + f_skew * y2
            # The measured sample the model output at k answers (a current read after
            # its voltage answers the model's later state).
            jm = k + lead  # (j is the eddy current)
            if k0 <= jm < k1:
                r = if_m[jm] - ym
                out[jm] = r
                sens[jm] = si
                s_rr += r * r
                s_rs += r * si
                s_ss += si * si
            if k >= n_int:
                continue
            v = mu[k, 0]
            rf = rf0 * (1.0 + theta[k]) if thermal else rf0
            if k2 > 0.0:
                if varying:
                    sat = 1.0 + c * abs(i)
                    p00, p01, p10, p11, g0, g1 = _eddy_step(rf, lf / (sat * sat), k2, te, dt)
                i_new = p00 * i + p01 * j + g0 * v
                j = p10 * i + p11 * j + g1 * v
                i = i_new
                si_new = p00 * si + p01 * sj
                sj = p10 * si + p11 * sj
                si = si_new
            else:
                if varying:
                    sat = 1.0 + c * abs(i)
                    if held:
                        a = math.exp(-rf * dt * sat * sat / lf)
                        c0 = (1.0 - a) / rf
                    else:
                        a, c0, c1, c2 = moment_coefficients(rf, lf / (sat * sat), dt)
                i = a * i + c0 * v + c1 * mu[k, 1] + c2 * mu[k, 2]
                si = a * si
                if si < 1e-150:
                    si = 0.0
        # A current read after its voltage at the record's end: its last samples are not
        # answered by a simulated state, and leave no residual.
        for jm in range(max(k0, k_end + lead), k1):
            out[jm] = 0.0
            sens[jm] = 0.0
        if s_ss > 0.0:
            delta = s_rs / s_ss
            for k in range(k0, k1):
                out[k] -= delta * sens[k]
            s_rr -= s_rs * delta
        sse += s_rr
    return sse


@njit(nogil=True, cache=True)
def armature_residual(
    p: np.ndarray,
    mu: np.ndarray,
    ia_m: np.ndarray,
    if_m: np.ndarray,
    omega: np.ndarray,
    loss: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    dt: float,
    brush_width_a: float,
    emf_constant: float,
    theta: np.ndarray,
    out: np.ndarray,
    emf_slope: bool = False,
    held: bool = True,
) -> tuple[float, float]:
    """Armature-current residual over the segments, ``K`` and per-segment ``i0`` projected.

    ``mu`` (n - 1, 3) are the armature voltage's moments per interval;
    ``emf_constant`` NaN fits ``K``; a number holds it. ``emf_slope``: the EMF
    is linear between samples (its slope enters through the first moment);
    else only its mean over the interval does (the trapezoid, held). Returns ``(sse, K)``;
    ``out`` receives the residual at the segments' samples.
    """
    ra0, la, c = p[I_RA], p[I_LA], p[I_SAT]
    vb, beta, off_f, off_a, skew = p[I_VB], p[I_BETA], p[I_OFF_IF], p[I_OFF_IA], p[I_SKEW]
    thermal_state(p, loss, dt, theta)
    thermal = p[I_KTH] != 0.0
    fit_k = math.isnan(emf_constant)
    m_skew = int(math.floor(skew / dt))
    f_skew = skew / dt - m_skew
    lead = min(m_skew, 0)  # as the field's
    a, c0, c1, c2 = _coefficients(ra0, la, dt, held)
    n_int = mu.shape[0]
    n_seg = starts.shape[0]
    # Per segment: sums for the Schur complement of the initial currents.
    s_de = 0.0
    s_ee = 0.0
    seg_dg = np.zeros(n_seg)
    seg_eg = np.zeros(n_seg)
    seg_gg = np.zeros(n_seg)
    dbuf = out  # d = target - forced response to u
    ebuf = theta  # theta is consumed sample by sample ahead of ebuf's write
    gbuf = np.empty(out.shape[0])
    for s in range(n_seg):
        k0, k1 = starts[s], stops[s]
        fv = 0.0
        fe = 0.0
        g = 1.0
        yv0 = yv1 = yv2 = 0.0
        ye0 = ye1 = ye2 = 0.0
        yg0 = yg1 = yg2 = 1.0
        q_prev = 0.0
        k_end = _skewed_end(k1, m_skew, ia_m.shape[0])
        for k in range(k0, k_end):
            yv2, yv1, yv0 = yv1, yv0, fv
            ye2, ye1, ye0 = ye1, ye0, fe
            yg2, yg1, yg0 = yg1, yg0, g
            if m_skew <= 0:
                sv = (1.0 - f_skew) * yv0 + f_skew * yv1
                se = (1.0 - f_skew) * ye0 + f_skew * ye1
                sg = (1.0 - f_skew) * yg0 + f_skew * yg1
            else:
                sv = (1.0 - f_skew) * yv1 + f_skew * yv2
                se = (1.0 - f_skew) * ye1 + f_skew * ye2
                sg = (1.0 - f_skew) * yg1 + f_skew * yg2
            if thermal:  # read theta[k] before ebuf (theta's memory) is written at k
                a, c0, c1, c2 = _coefficients(ra0 * (1.0 + theta[k]), la, dt, held)
            jm = k + lead  # the measured sample answered (as the field's)
            if k0 <= jm < k1:
                d = ia_m[jm] - off_a - sv
                if not fit_k:
                    d += emf_constant * se
                dbuf[jm] = d
                ebuf[jm] = se
                gbuf[jm] = sg
                s_de += d * se
                s_ee += se * se
                seg_dg[s] += d * sg
                seg_eg[s] += se * sg
                seg_gg[s] += sg * sg
            # The measured currents are read the skew late: as model inputs, read them ahead.
            ia_true = _advanced(ia_m, k, m_skew, f_skew) - off_a
            # Inputs over [k, k+1]: the voltage's moments less the brush drop (held),
            # the EMF linear between samples (its mean and slope moments).
            kv = k if k < n_int else n_int - 1
            u = mu[kv, 0]
            if vb != 0.0:
                u -= vb * math.tanh(ia_true / brush_width_a)
            if k == k0:
                i_f = _advanced(if_m, k, m_skew, f_skew) - off_f
                ia_k = _advanced(ia_m, k, m_skew, f_skew) - off_a
                q_prev = i_f / (1.0 + c * abs(i_f)) * (1.0 - beta * abs(ia_k)) * omega[k]
            kn = k + 1 if k + 1 < k_end else k
            i_fn = _advanced(if_m, kn, m_skew, f_skew) - off_f
            ia_n = _advanced(ia_m, kn, m_skew, f_skew) - off_a
            q_next = i_fn / (1.0 + c * abs(i_fn)) * (1.0 - beta * abs(ia_n)) * omega[kn]
            e = 0.5 * (q_prev + q_next)
            e1 = (q_next - q_prev) / 6.0 if emf_slope else 0.0
            q_prev = q_next
            fv = a * fv + c0 * u + c1 * mu[kv, 1] + c2 * mu[kv, 2]
            fe = a * fe + c0 * e + c1 * e1
            gg = a * g
            g = gg if abs(gg) > 1e-150 else 0.0
        for jm in range(max(k0, k_end + lead), k1):  # unanswered (see the field's)
            dbuf[jm] = 0.0
            ebuf[jm] = 0.0
            gbuf[jm] = 0.0
    return _project_emf_and_initial_currents(
        dbuf, ebuf, gbuf, s_de, s_ee, seg_dg, seg_eg, seg_gg, starts, stops, fit_k,
        emf_constant, out,
    )  # fmt: skip


@njit(nogil=True, cache=True)
def _project_emf_and_initial_currents(
    d: np.ndarray,
    e: np.ndarray,
    g: np.ndarray,
    s_de: float,
    s_ee: float,
    seg_dg: np.ndarray,
    seg_eg: np.ndarray,
    seg_gg: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    fit_k: bool,
    emf_constant: float,
    out: np.ndarray,
) -> tuple[float, float]:
    """The armature residual's second pass: ``K`` and each segment's ``i0`` projected out.

    ``d`` is the current less the forced response, ``e`` the response to the
    EMF input and ``g`` the free response (per sample); ``s_de``, ``s_ee`` and
    the per-segment ``seg_*`` are their sums. Writes the residual into ``out``
    (which may be ``d``) and returns ``(sse, K)``.
    """
    n_seg = starts.shape[0]
    # d ~ -K*e + i0_s*g: eliminate i0_s per segment, then K.
    ee = s_ee
    de = s_de
    for s in range(n_seg):
        if seg_gg[s] > 0.0:
            ee -= seg_eg[s] * seg_eg[s] / seg_gg[s]
            de -= seg_dg[s] * seg_eg[s] / seg_gg[s]
    kk = 0.0
    if fit_k and ee > 1e-300:
        kk = -de / ee
    k_out = kk if fit_k else emf_constant
    sse = 0.0
    for s in range(n_seg):
        k0, k1 = starts[s], stops[s]
        i0 = 0.0
        if seg_gg[s] > 0.0:
            i0 = (seg_dg[s] + kk * seg_eg[s]) / seg_gg[s]
        for k in range(k0, k1):
            r = d[k] + kk * e[k] - i0 * g[k]
            out[k] = r
            sse += r * r
    return sse, k_out


@njit(nogil=True, cache=True)
def field_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    if_m: np.ndarray,
    loss: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    dt: float,
    held: bool = True,
) -> np.ndarray:
    """SSE of :func:`field_residual` for every row of ``positions`` (n_particles, N_FULL)."""
    n_p = positions.shape[0]
    n = if_m.shape[0]
    out = np.empty(n_p)
    theta = np.empty(n)
    res = np.empty(n)
    for p in range(n_p):
        out[p] = field_residual(positions[p], mu, if_m, loss, starts, stops, dt, theta, res, held)
    return out


@njit(nogil=True, cache=True)
def armature_swarm_costs(
    positions: np.ndarray,
    mu: np.ndarray,
    ia_m: np.ndarray,
    if_m: np.ndarray,
    omega: np.ndarray,
    loss: np.ndarray,
    starts: np.ndarray,
    stops: np.ndarray,
    dt: float,
    brush_width_a: float,
    emf_slope: bool = False,
    held: bool = True,
) -> np.ndarray:
    """SSE of :func:`armature_residual` (``K`` fitted) for every row of ``positions``."""
    n_p = positions.shape[0]
    n = ia_m.shape[0]
    out = np.empty(n_p)
    theta = np.empty(n)
    res = np.empty(n)
    for p in range(n_p):
        sse, _ = armature_residual(
            positions[p], mu, ia_m, if_m, omega, loss, starts, stops, dt, brush_width_a,
            math.nan, theta, res, emf_slope, held,
        )  # fmt: skip
        out[p] = sse
    return out
