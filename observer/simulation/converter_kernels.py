"""Numba kernel of a converter-fed DC drive and its analog front end, integrated far finer than
the sample rate.

The plant (field with optional eddy path, armature, mechanics, winding temperature, shaft angle)
and the analog anti-aliasing filters are integrated together by RK4 with exact events: every
thyristor firing, natural commutation point, PWM edge, controller tick, sample instant and
sample-period boundary is a step boundary, and no step is longer than ``h_max`` (5 us by
default). A current zero of the armature bridge (discontinuous conduction) and the end of a
commutation overlap are located inside a step and the step is redone up to them.

Converters (the full equations, sizing and controller in ``docs/drive_chain.md``):

- armature: ideal (voltage held per sample: today's simulator), a dual circulating-current-free
  6-pulse thyristor bridge, or a 4-quadrant H-bridge chopper with unipolar PWM;
- field: ideal (held per sample), a single-phase fully controlled bridge, a 3-phase
  half-controlled bridge with freewheeling diode, or a chopper.

In short (``b = +-1`` the active bridge, ``e = K if omega`` the back-EMF, ``Lc`` the source
inductance per phase)::

    armature       (La + Ls) dia/dt = u - Ra ia - e,       va = u - Ls dia/dt
    6-pulse        u = b sqrt(2) V_LL cos(w t + phi0 - j pi/3) for the conducting pair j,
                   fired alpha/w after its natural point; mean 1.35 V_LL cos(alpha); Ls = 2 Lc
    overlap        u = b (u_new + u_old)/2, Ls = 1.5 Lc, until the incoming current is ia
    DCM            b ia reaching 0 blocks the bridge: ia = 0, va = e, until a firing with
                   b (b u_j - e) > 0
    changeover     only at zero current, after dead_time, at a natural point
    chopper        u in {-Vdc, 0, +Vdc}, centred unipolar PWM, mean d Vdc, pulses at 2 f_sw
    field 1p       vf = s sqrt(2) Vs sin(w t + phi_f), s alternating per half period;
                   mean 0.9 Vs cos(alpha), ripple at 2x mains
    field half-3p  vf = max(u_p - min(u_a, u_b, u_c), 0); mean 1.35 V_LL (1 + cos(alpha))/2
    filters        sections w0/(s + w0) and w0^2/(s^2 + (w0/Q) s + w0^2) per channel, states
                   of this kernel; a sample is y(kT + delay) or its mean over the period

The whole simulation state (continuous states, converter modes, controller integrators, pending
firings and PWM edges, per-channel sample counters) lives in one float64 vector made by
:func:`initial_state` and advanced in place by :func:`advance`, so a stream made of many calls is
exactly the stream of one call. The Python driver is :mod:`observer.simulation.converter_drive`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from observer.simulation.kernels import drive_controller_step, speed_loop

# converter kinds
ARM_IDEAL = 0
ARM_THYRISTOR_6P = 1
ARM_CHOPPER = 2
FLD_IDEAL = 0
FLD_BRIDGE_1P = 1
FLD_HALF_3P = 2
FLD_CHOPPER = 3

# ---- continuous states y
S_IF, S_J, S_IA, S_W, S_TH, S_ANG, S_Q, S_ZVA, S_ZVF = 0, 1, 2, 3, 4, 5, 6, 7, 8
S_FILT = 9  # 5 channels x 2 sections x 2 states
S_ZCH = S_FILT + 20  # running integral of each channel's filtered signal (averaging ADC)
S_M = S_ZCH + 5  # moments of va, vf over the current sample period: va*u, va*u^2, vf*u, vf*u^2
S_QIA = S_M + 4  # running integral of ia: the thyristor drive measures the mean current per pulse
N_Y = S_QIA + 1

# ---- converter modes (after y in the state vector)
M_ARM_COND = 0  # armature bridge conducting (1) or blocked (0)
M_ARM_PAIR = 1  # conducting thyristor pair 0..5
M_BRIDGE = 2  # active bridge +1 / -1
M_OVERLAP = 3  # commutation overlap in progress
M_OLD_PAIR = 4  # outgoing pair during the overlap
M_ARM_LEVEL = 5  # ideal / chopper armature source voltage
M_FLD_COND = 6  # field bridge conducting
M_FLD_PAIR = 7  # field bridge: sign of the conducting pair (1p) or conducting phase (3p)
M_FLD_LEVEL = 8  # ideal / chopper field source voltage
M_T0 = 9  # start of the current sample period
M_DT = 10  # sample period
N_MODE = 11
MODE = N_Y

# ---- scalars of the controllers and the event schedule
_B = MODE + N_MODE
C_T = _B  # simulated time
C_K = _B + 1  # next sample-period boundary to process (absolute sample index)
C_W_REF = _B + 2
C_INT_W = _B + 3
C_INT_I = _B + 4
C_INHIBIT = _B + 5  # bridge changeover requested
C_DEAD_START = _B + 6  # start of the changeover dead time (-1: not started)
C_P_NEXT = _B + 7  # index of the next natural point of the armature bridge
C_T_NAT = _B + 8
C_LAST_FIRE = _B + 9
C_T_CAR = _B + 10  # next armature PWM carrier period
C_PF_NEXT = _B + 11  # next natural point of the field bridge
C_TF_NAT = _B + 12
C_T_QIA = _B + 13  # start of the current integral of ia (-1: none yet)
C_TF_CAR = _B + 14
C_T_IDEAL = _B + 15  # next controller tick of an ideal converter
C_TICK = _B + 16  # controller measurements so far (counter of the drive's sensor noise)
_A = _B + 17
Q_FIRE = 8  # pending armature firings
A_FIRE_T = _A
A_FIRE_J = _A + Q_FIRE
A_FIRE_B = _A + 2 * Q_FIRE
A_SW_T = _A + 3 * Q_FIRE  # pending PWM edges (time, level)
A_SW_LV = A_SW_T + 4
A_FSW_T = A_SW_LV + 4
A_FSW_LV = A_FSW_T + 4
Q_FFIRE = 2  # pending field firings (the half-controlled bridge fires up to 175 deg late, beyond
A_FFIRE_T = A_FSW_LV + 4  # the next natural point 120 deg on)
A_FFIRE_P = A_FFIRE_T + Q_FFIRE
A_KS = A_FFIRE_P + Q_FFIRE  # next sample index per channel
A_ZSET = A_KS + 5  # the averaging channel's integral has run for a whole period
STATE_SIZE = A_ZSET + 5

# ---- truth columns of :func:`advance`
T_VA_MEAN, T_IA, T_VF_MEAN, T_IF, T_OMEGA, T_THETA, T_VA, T_VF = 0, 1, 2, 3, 4, 5, 6, 7
T_MOMENTS = 8  # mean of va*u, va*u^2, vf*u, vf*u^2 over the period (u = (t - kT)/T)
T_BRIDGE, T_CONDUCTING, T_EMF, T_ANGLE = 12, 13, 14, 15
N_TRUTH = 16

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@njit(nogil=True, cache=True)
def _uniform(seed: int, counter: int) -> float:
    """A uniform number in (0, 1] from (seed, counter): splitmix64, independent of chunking."""
    z = np.uint64(seed) * _GOLDEN + np.uint64(counter)
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    z = z ^ (z >> np.uint64(31))
    return ((z >> np.uint64(11)) + np.uint64(1)) * (1.0 / 9007199254740992.0)


@njit(nogil=True, cache=True)
def _normal(seed: int, counter: int) -> float:
    u1 = _uniform(seed, 2 * counter)
    u2 = _uniform(seed, 2 * counter + 1)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(nogil=True, cache=True)
def _u_ll(j: int, t: float, amp: float, wm: float, phi: float) -> float:
    """Line-to-line voltage of 6-pulse pair j: ``amp*cos(wm*t + phi - j*pi/3)``."""
    return amp * math.cos(wm * t + phi - j * math.pi / 3.0)


@njit(nogil=True, cache=True)
def _phase(p: int, t: float, amp: float, wm: float, phi: float) -> float:
    return amp * math.sin(wm * t + phi - p * 2.0 * math.pi / 3.0)


@njit(nogil=True, cache=True)
def _field_source(t: float, fld: np.ndarray, mode: np.ndarray) -> float:
    """Voltage the field converter applies while it conducts."""
    fkind = int(fld[0])
    if fkind == FLD_IDEAL or fkind == FLD_CHOPPER:
        return mode[M_FLD_LEVEL]
    if fkind == FLD_BRIDGE_1P:
        return mode[M_FLD_PAIR] * fld[1] * math.sin(fld[2] * t + fld[3])
    # half-controlled 3-phase: the fired phase against the lowest one, freewheeling below zero
    p = int(mode[M_FLD_PAIR])
    amp, wf, phf = fld[1], fld[2], fld[3]
    ut = _phase(p, t, amp, wf, phf)
    umin = min(_phase(0, t, amp, wf, phf), min(_phase(1, t, amp, wf, phf),
                                               _phase(2, t, amp, wf, phf)))  # fmt: skip
    return max(ut - umin, 0.0)


@njit(nogil=True, cache=True)
def _back_emf(y: np.ndarray, motor: np.ndarray, fx: np.ndarray) -> float:
    """``K * flux * omega``, with saturation, armature reaction and the commutation ripple."""
    i_f, ia = y[S_IF], y[S_IA]
    flux = i_f / (1.0 + fx[0] * abs(i_f)) * (1.0 - fx[5] * abs(ia))
    e_back = motor[4] * flux * y[S_W]
    if fx[8] > 0.0:
        e_back *= 1.0 + fx[8] * math.cos(fx[9] * y[S_ANG])
    return float(e_back)


@njit(nogil=True, cache=True)
def _deriv(
    t: float,
    y: np.ndarray,
    dy: np.ndarray,
    raw: np.ndarray,
    motor: np.ndarray,
    fx: np.ndarray,
    arm: np.ndarray,
    fld: np.ndarray,
    filt: np.ndarray,
    mode: np.ndarray,
    tl: float,
) -> None:
    """Derivatives of every state at ``t``; ``raw`` receives the five physical signals."""
    rf0, lf, ra0, la, k_emf = motor[0], motor[1], motor[2], motor[3], motor[4]
    inertia, friction = motor[5], motor[6]
    c_sat, kth, tth, vb, iw, beta, k2, te = fx[0], fx[1], fx[2], fx[3], fx[4], fx[5], fx[6], fx[7]
    tacho_g, irated = fx[10], fx[11]
    i_f, j_ed, ia, w, theta = y[S_IF], y[S_J], y[S_IA], y[S_W], y[S_TH]
    rf = rf0 * (1.0 + theta)
    ra = ra0 * (1.0 + theta)
    s = 1.0 + c_sat * abs(i_f)
    flux = i_f / s * (1.0 - beta * abs(ia))
    l_inc = lf / (s * s)
    e_back = _back_emf(y, motor, fx)
    # ---- field
    if mode[M_FLD_COND] > 0.5:
        vf_term = _field_source(t, fld, mode)
        if k2 > 0.0:
            dif = ((vf_term - rf * i_f) / l_inc + j_ed / te) / (1.0 - k2)
            dj = -j_ed / te - k2 * dif
        else:
            dif = (vf_term - rf * i_f) / l_inc
            dj = 0.0
    else:
        vf_term = 0.0
        dif = 0.0
        dj = -j_ed / te if k2 > 0.0 else 0.0
    # ---- armature
    drop = vb * math.tanh(ia / iw) if vb > 0.0 else 0.0
    dq = 0.0
    if int(arm[0]) == ARM_THYRISTOR_6P:
        amp, wm, phi, lc = arm[1], arm[2], arm[3], arm[4]
        b = mode[M_BRIDGE]
        if mode[M_ARM_COND] > 0.5:
            jn = int(mode[M_ARM_PAIR])
            if mode[M_OVERLAP] > 0.5:
                # commutation overlap: both pairs conduct through the source inductances
                un = _u_ll(jn, t, amp, wm, phi)
                uo = _u_ll(int(mode[M_OLD_PAIR]), t, amp, wm, phi)
                src = b * 0.5 * (un + uo)
                ls = 1.5 * lc
            else:
                src = b * _u_ll(jn, t, amp, wm, phi)
                ls = 2.0 * lc
            dia = (src - ra * ia - drop - e_back) / (la + ls)
            va_term = src - ls * dia
            if mode[M_OVERLAP] > 0.5:
                # the incoming phase's current: Lc*(di_in - di_out)/dt = u_in - u_out
                dq = b * (un - uo) / (2.0 * lc) + 0.5 * dia
        else:
            dia = 0.0
            va_term = e_back  # blocked: the terminals show the back-EMF
    else:
        src = mode[M_ARM_LEVEL]
        ls = arm[4]
        dia = (src - ra * ia - drop - e_back) / (la + ls)
        va_term = src - ls * dia
    dw = (k_emf * flux * ia - friction * w - tl) / inertia
    loss = ra * ia * ia + rf * i_f * i_f  # copper loss at the hot resistances
    dth = (kth * loss - theta) / tth if kth > 0.0 else 0.0
    dy[S_IF] = dif
    dy[S_J] = dj
    dy[S_IA] = dia
    dy[S_W] = dw
    dy[S_TH] = dth
    dy[S_ANG] = w
    dy[S_Q] = dq
    dy[S_ZVA] = va_term
    dy[S_ZVF] = vf_term
    uu = (t - mode[M_T0]) / mode[M_DT]
    dy[S_M] = va_term * uu
    dy[S_M + 1] = va_term * uu * uu
    dy[S_M + 2] = vf_term * uu
    dy[S_M + 3] = vf_term * uu * uu
    dy[S_QIA] = ia
    raw[0] = va_term
    raw[1] = ia
    raw[2] = vf_term
    raw[3] = i_f
    raw[4] = fx[12] * (w * (1.0 - tacho_g * abs(ia) / irated) if tacho_g > 0.0 else w)
    # ---- analog filters: per channel up to two sections (kind, w0, Q) in cascade
    for c in range(5):
        u = raw[c]
        base = S_FILT + 4 * c
        for sec in range(2):
            kind = int(filt[c, sec, 0])
            x0 = base + 2 * sec
            if kind == 0:
                dy[x0] = 0.0
                dy[x0 + 1] = 0.0
                continue
            w0 = filt[c, sec, 1]
            if kind == 1:
                dy[x0] = w0 * (u - y[x0])
                dy[x0 + 1] = 0.0
            else:
                q = filt[c, sec, 2]
                dy[x0] = y[x0 + 1]
                dy[x0 + 1] = w0 * w0 * (u - y[x0]) - (w0 / q) * y[x0 + 1]
            u = y[x0]
        dy[S_ZCH + c] = u


@njit(nogil=True, cache=True)
def _filtered(y: np.ndarray, raw: np.ndarray, filt: np.ndarray, c: int) -> float:
    """Output of channel ``c``'s filter (its input if it has none)."""
    u = raw[c]
    base = S_FILT + 4 * c
    for sec in range(2):
        if int(filt[c, sec, 0]) != 0:
            u = y[base + 2 * sec]
    return u


@njit(nogil=True, cache=True)
def _rk4(
    t: float,
    y: np.ndarray,
    h: float,
    ytmp: np.ndarray,
    k1: np.ndarray,
    k2: np.ndarray,
    k3: np.ndarray,
    k4: np.ndarray,
    raw: np.ndarray,
    motor: np.ndarray,
    fx: np.ndarray,
    arm: np.ndarray,
    fld: np.ndarray,
    filt: np.ndarray,
    mode: np.ndarray,
    tl: float,
    out: np.ndarray,
) -> None:
    n = y.shape[0]
    _deriv(t, y, k1, raw, motor, fx, arm, fld, filt, mode, tl)
    for i in range(n):
        ytmp[i] = y[i] + 0.5 * h * k1[i]
    _deriv(t + 0.5 * h, ytmp, k2, raw, motor, fx, arm, fld, filt, mode, tl)
    for i in range(n):
        ytmp[i] = y[i] + 0.5 * h * k2[i]
    _deriv(t + 0.5 * h, ytmp, k3, raw, motor, fx, arm, fld, filt, mode, tl)
    for i in range(n):
        ytmp[i] = y[i] + h * k3[i]
    _deriv(t + h, ytmp, k4, raw, motor, fx, arm, fld, filt, mode, tl)
    for i in range(n):
        out[i] = y[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0


@njit(nogil=True, cache=True)
def _first_natural_point(phi: float, step: float, offset: float, w: float) -> tuple[int, float]:
    """Index and time (>= 0) of the first natural point ``w*t + phi = p*step + offset``."""
    p = int(math.ceil((phi - offset) / step))
    t = (p * step + offset - phi) / w
    while t < 0.0:
        p += 1
        t = (p * step + offset - phi) / w
    return p, t


@njit(nogil=True, cache=True)
def initial_state(
    motor: np.ndarray,
    fx: np.ndarray,
    arm: np.ndarray,
    fld: np.ndarray,
    filt: np.ndarray,
    dt: float,
    i_f0: float,
    ia0: float,
    omega0: float,
) -> np.ndarray:
    """The state at t = 0: currents and speed given, filters settled at their inputs, the
    converters' first natural points scheduled, nothing pending."""
    state = np.zeros(STATE_SIZE)
    y = state[:N_Y]
    mode = state[MODE : MODE + N_MODE]
    y[S_IF] = i_f0
    y[S_IA] = ia0
    y[S_W] = omega0
    mode[M_DT] = dt
    mode[M_BRIDGE] = 1.0 if ia0 >= 0.0 else -1.0
    # a thyristor bridge at zero current is blocked; the other converters always conduct
    mode[M_ARM_COND] = 1.0 if ia0 != 0.0 or int(arm[0]) != ARM_THYRISTOR_6P else 0.0
    akind = int(arm[0])
    fkind = int(fld[0])
    state[C_W_REF] = omega0
    state[C_DEAD_START] = -1.0
    state[C_LAST_FIRE] = -1.0
    state[C_T_NAT] = np.inf
    state[C_TF_NAT] = np.inf
    state[C_T_QIA] = -1.0
    for q in range(Q_FFIRE):
        state[A_FFIRE_T + q] = np.inf
    state[C_T_CAR] = np.inf
    state[C_TF_CAR] = np.inf
    state[C_T_IDEAL] = np.inf
    if akind == ARM_THYRISTOR_6P:
        # natural points of the 6-pulse bridge: wm*t + phi = p*pi/3 - pi/6
        p, t_nat = _first_natural_point(arm[3], math.pi / 3.0, -math.pi / 6.0, arm[2])
        state[C_P_NEXT] = p
        state[C_T_NAT] = t_nat
        mode[M_ARM_PAIR] = (p - 1) % 6
    elif akind == ARM_CHOPPER:
        # the carrier period that contains t = 0 (its start is processed at once)
        state[C_T_CAR] = ((arm[3] / (2.0 * math.pi)) % 1.0 - 1.0) / arm[2]
    if fkind == FLD_BRIDGE_1P or fkind == FLD_HALF_3P:
        step = math.pi if fkind == FLD_BRIDGE_1P else 2.0 * math.pi / 3.0
        off = 0.0 if fkind == FLD_BRIDGE_1P else math.pi / 6.0
        p, t_nat = _first_natural_point(fld[3], step, off, fld[2])
        state[C_PF_NEXT] = p
        state[C_TF_NAT] = t_nat
        # an established field conducts from the start on the pair fired before
        mode[M_FLD_COND] = 1.0 if i_f0 > 0.0 else 0.0
        if fkind == FLD_BRIDGE_1P:
            mode[M_FLD_PAIR] = 1.0 if (p - 1) % 2 == 0 else -1.0
        else:
            mode[M_FLD_PAIR] = float((p - 1) % 3)
    else:
        mode[M_FLD_COND] = 1.0
    if fkind == FLD_CHOPPER:
        state[C_TF_CAR] = ((fld[3] / (2.0 * math.pi)) % 1.0 - 1.0) / fld[2]
    if akind == ARM_IDEAL or fkind == FLD_IDEAL:
        state[C_T_IDEAL] = 0.0
    for q in range(Q_FIRE):
        state[A_FIRE_T + q] = np.inf
    for r in range(4):
        state[A_SW_T + r] = np.inf
        state[A_FSW_T + r] = np.inf
    # filters settled at their initial inputs
    raw = np.zeros(5)
    dy = np.zeros(N_Y)
    _deriv(0.0, y, dy, raw, motor, fx, arm, fld, filt, mode, 0.0)
    for c in range(5):
        for sec in range(2):
            if int(filt[c, sec, 0]) != 0:
                y[S_FILT + 4 * c + 2 * sec] = raw[c]
    return state


@njit(nogil=True, cache=True)
def _pwm_edges(t: float, period: float, d: float, amp: float, sw_t: np.ndarray,
               sw_lv: np.ndarray) -> None:  # fmt: skip
    """Schedule one carrier period of unipolar, centred PWM with duty ``d`` in [-1, 1].

    Leg A is high for ``(1 + d)/2`` of the period, leg B for ``(1 - d)/2``, both centred; the
    output is ``amp*(A - B)``: pulses of +-amp at twice the carrier frequency.
    """
    da = 0.5 * (1.0 + d)
    db = 0.5 * (1.0 - d)
    ev = np.array([t + 0.5 * (1.0 - da) * period, t + 0.5 * (1.0 + da) * period,
                   t + 0.5 * (1.0 - db) * period, t + 0.5 * (1.0 + db) * period])  # fmt: skip
    order = np.argsort(ev)
    leg_a = 0.0
    leg_b = 0.0
    for r in range(4):
        e = order[r]
        if e == 0:
            leg_a = 1.0
        elif e == 1:
            leg_a = 0.0
        elif e == 2:
            leg_b = 1.0
        else:
            leg_b = 0.0
        sw_t[r] = ev[e]
        sw_lv[r] = amp * (leg_a - leg_b)


@njit(nogil=True, cache=True)
def advance(
    state: np.ndarray,
    n: int,
    h_max: float,
    motor: np.ndarray,
    fx: np.ndarray,
    arm: np.ndarray,
    fld: np.ndarray,
    ctrl: np.ndarray,
    filt: np.ndarray,
    delays: np.ndarray,
    averaging: np.ndarray,
    drive_noise: np.ndarray,
    seed: int,
    speed_ref: np.ndarray,
    torque_load: np.ndarray,
    vf_ref: np.ndarray,
    schedule: np.ndarray,
    want_truth: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate the next ``n`` sample periods from ``state`` (updated in place).

    Parameters
    ----------
    state : (STATE_SIZE,) array
        From :func:`initial_state` or the previous call; its sample index ``k0`` (the first
        sample of this call) is ``state[C_K]``.
    h_max : float
        Longest integration step (s).
    motor : (7,) array
        ``Rf, Lf, Ra, La, K, J, B``.
    fx : (13,) array
        :meth:`observer.simulation.effects_sim.PlantEffects.plant_array` followed by the back-EMF
        ripple amplitude (fraction) and its number per revolution, the tachometer's gain loss
        at ``irated``, ``irated`` (A) and the tachometer's gain (1.0; ``schedule`` changes it).
    arm : (9,) array
        ``kind, amplitude, omega, phase, L_source, alpha_min, alpha_max, dead_time, i_hyst``:
        for the thyristor bridge the line-to-line peak (V), mains angular frequency (rad/s),
        mains phase at t = 0, source inductance per phase (H), firing limits (rad), changeover
        dead time (s) and the current-reference hysteresis of a changeover request (A); for
        the chopper the DC link (V), the carrier frequency (Hz), the carrier phase and a series
        inductance (H).
    fld : (7,) array
        ``kind, amplitude, omega, phase, alpha_min, alpha_max, Vd0``: source peak (V; phase peak
        for the 3-phase bridge), mains angular frequency, phase, firing limits (rad) and the
        bridge's no-load average voltage at alpha = 0; for the chopper the DC link (V), the
        carrier frequency (Hz) and its phase.
    ctrl : (8,) array
        ``kp_i, ki_i, kp_w, ki_w, i_limit, v_limit, ramp, K_nominal`` of the cascade controller.
    filt : (5, 2, 3) array
        Filter sections per channel (:func:`observer.simulation.chain.filter_sections`).
    delays, averaging : (5,) arrays
        Sampling delay (s, below one period) and 1.0 for an averaging channel.
    drive_noise : (3,) array
        Standard deviation of the drive's own ``ia, if, omega`` sensors (its controller's input).
    seed : int
        Seed of the drive's sensor noise (counter-based: independent of how calls are split).
    speed_ref, torque_load, vf_ref : (n,) arrays
        Speed reference (rad/s), load torque (N*m) and field voltage reference (V) per period.
    schedule : (n, 6) or (0, 6) array
        Per period, multipliers of ``Rf, Lf, Ra, La, K`` and the tachometer's gain
        (:func:`observer.simulation.effects_sim.change_schedule`); no rows: none.
    want_truth : bool
        Fill the truth array (else it has one row, unused).

    Returns
    -------
    samples : (n, 5) array
        ``va, ia, vf, if, omega`` after each channel's filter, at ``kT + delay`` (averaging
        channels: the mean over the period ending there; the stream's very first sample of an
        averaging channel is the instantaneous value).
    truth : (n, N_TRUTH) array
        Per sample (columns ``T_*``): mean terminal voltages over ``[kT, (k+1)T)``, states at
        ``kT``, instantaneous terminal voltages, the voltages' first and second moments over
        the period, active bridge, conduction, back-EMF and shaft angle.
    """
    y = state[:N_Y]
    mode = state[MODE : MODE + N_MODE]
    fire_t = state[A_FIRE_T : A_FIRE_T + Q_FIRE]
    fire_j = state[A_FIRE_J : A_FIRE_J + Q_FIRE]
    fire_b = state[A_FIRE_B : A_FIRE_B + Q_FIRE]
    sw_t = state[A_SW_T : A_SW_T + 4]
    sw_lv = state[A_SW_LV : A_SW_LV + 4]
    fsw_t = state[A_FSW_T : A_FSW_T + 4]
    fsw_lv = state[A_FSW_LV : A_FSW_LV + 4]
    ks = state[A_KS : A_KS + 5]
    z_set = state[A_ZSET : A_ZSET + 5]
    t = state[C_T]
    k_next = int(state[C_K])
    k0 = k_next
    w_ref, int_w, int_i = state[C_W_REF], state[C_INT_W], state[C_INT_I]
    inhibit = state[C_INHIBIT] > 0.5
    dead_start = state[C_DEAD_START]
    p_next = int(state[C_P_NEXT])
    t_nat = state[C_T_NAT]
    last_fire = state[C_LAST_FIRE]
    t_car = state[C_T_CAR]
    pf_next = int(state[C_PF_NEXT])
    tf_nat = state[C_TF_NAT]
    ffire_t = state[A_FFIRE_T : A_FFIRE_T + Q_FFIRE]
    ffire_p = state[A_FFIRE_P : A_FFIRE_P + Q_FFIRE]
    t_qia = state[C_T_QIA]
    tf_car = state[C_TF_CAR]
    t_ideal = state[C_T_IDEAL]
    tick = int(state[C_TICK])

    dt = mode[M_DT]
    motor_base = motor
    motor = motor_base.copy()  # the parameters now, after the schedule's steps
    fx = fx.copy()
    scheduled = schedule.shape[0] > 0
    akind = int(arm[0])
    fkind = int(fld[0])
    ynew = np.zeros(N_Y)
    ytmp = np.zeros(N_Y)
    k1 = np.zeros(N_Y)
    k2 = np.zeros(N_Y)
    k3 = np.zeros(N_Y)
    k4 = np.zeros(N_Y)
    raw = np.zeros(5)
    samples = np.zeros((n, 5))
    truth = np.zeros((n if want_truth else 1, N_TRUTH))
    k_end = k0 + n
    t_end = k_end * dt
    kp_i, ki_i = ctrl[0], ctrl[1]
    k_nom = ctrl[7]
    sig_i, sig_f, sig_w = drive_noise[0], drive_noise[1], drive_noise[2]
    amp_a, wm_a, phi_a, lc = arm[1], arm[2], arm[3], arm[4]
    a_min, a_max, t_dead, i_hyst = arm[5], arm[6], arm[7], arm[8]
    vd0 = 3.0 / math.pi * amp_a  # 1.35 V_LL of the 6-pulse bridge
    t_pulse = math.pi / (3.0 * wm_a) if akind == ARM_THYRISTOR_6P else 0.0
    t_sw = 1.0 / arm[2] if akind == ARM_CHOPPER else 0.0
    wf, phf = fld[2], fld[3]
    fa_min, fa_max, fvd0 = fld[4], fld[5], fld[6]
    f_step = math.pi if fkind == FLD_BRIDGE_1P else 2.0 * math.pi / 3.0
    f_off = math.pi / 6.0 if fkind == FLD_HALF_3P else 0.0
    tf_sw = 1.0 / fld[2] if fkind == FLD_CHOPPER else 0.0
    control = ctrl[:7]
    k_cur = k0  # the sample period t lies in
    while True:
        eps = 1e-12 + 4.5e-16 * abs(t)
        # ------------------------------------------------ sample-period boundaries due now
        while k_next <= k_end and k_next * dt <= t + eps:
            _deriv(t, y, k1, raw, motor, fx, arm, fld, filt, mode, 0.0)
            row = k_next - 1 - k0
            if want_truth and row >= 0:
                truth[row, T_VA_MEAN] = y[S_ZVA] / dt
                truth[row, T_VF_MEAN] = y[S_ZVF] / dt
                for jj in range(4):
                    truth[row, T_MOMENTS + jj] = y[S_M + jj] / dt
            for jj in range(4):
                y[S_M + jj] = 0.0
            mode[M_T0] = k_next * dt
            # integrals restart at every boundary, so they never grow (a stream runs for days)
            y[S_ZVA] = 0.0
            y[S_ZVF] = 0.0
            row += 1
            if want_truth and row < n:
                truth[row, T_IA] = y[S_IA]
                truth[row, T_IF] = y[S_IF]
                truth[row, T_OMEGA] = y[S_W]
                truth[row, T_THETA] = y[S_TH]
                truth[row, T_VA] = raw[0]
                truth[row, T_VF] = raw[2]
                truth[row, T_BRIDGE] = mode[M_BRIDGE]
                truth[row, T_CONDUCTING] = mode[M_ARM_COND]
                truth[row, T_ANGLE] = y[S_ANG]
                truth[row, T_EMF] = _back_emf(y, motor, fx)
            k_cur = k_next
            if scheduled:
                srow = min(max(k_cur - k0, 0), n - 1)
                for i in range(5):
                    motor[i] = motor_base[i] * schedule[srow, i]
                fx[12] = schedule[srow, 5]
            if k_next == k_end:
                break  # the next call processes this boundary's sample again
            k_next += 1
        if t >= t_end - eps:
            break
        kprof = min(max(k_cur - k0, 0), n - 1)
        tl = torque_load[kprof]
        # ------------------------------------------------ ideal converters: once per sample
        if (akind == ARM_IDEAL or fkind == FLD_IDEAL) and t_ideal <= t + eps:
            if akind == ARM_IDEAL:
                ia_m = y[S_IA] + sig_i * _normal(seed, 3 * tick)
                if_m = y[S_IF] + sig_f * _normal(seed, 3 * tick + 1)
                w_m = fx[12] * y[S_W] + sig_w * _normal(seed, 3 * tick + 2)
                tick += 1
                va, w_ref, int_w, int_i = drive_controller_step(
                    control, k_nom, dt, speed_ref[kprof], ia_m, if_m, w_m, w_ref, int_w, int_i
                )
                mode[M_ARM_LEVEL] = va
            if fkind == FLD_IDEAL:
                mode[M_FLD_LEVEL] = vf_ref[kprof]
            t_ideal = (k_cur + 1) * dt
        # ------------------------------------------------ thyristor bridge: natural point
        if akind == ARM_THYRISTOR_6P and t_nat <= t + eps:
            # the drive measures the mean current over the last pulse (synchronous sampling
            # would see one phase of the 6-pulse ripple and regulate its peak instead)
            ia_mean = y[S_IA]
            if t_qia >= 0.0 and t > t_qia:
                ia_mean = y[S_QIA] / (t - t_qia)
            y[S_QIA] = 0.0
            t_qia = t
            ia_m = ia_mean + sig_i * _normal(seed, 3 * tick)
            if_m = y[S_IF] + sig_f * _normal(seed, 3 * tick + 1)
            w_m = fx[12] * y[S_W] + sig_w * _normal(seed, 3 * tick + 2)
            tick += 1
            i_ref, w_ref, int_w = speed_loop(ctrl, t_pulse, speed_ref[kprof], w_m, w_ref, int_w)
            b = mode[M_BRIDGE]
            if not inhibit and b * i_ref < -i_hyst:
                inhibit = True  # torque reversal requested: change bridges
                dead_start = -1.0
            if inhibit and b * i_ref > i_hyst:
                inhibit = False  # request withdrawn
            fire = True
            alpha = a_max
            if inhibit:
                if mode[M_ARM_COND] < 0.5:
                    fire = False
                    if dead_start < 0.0:
                        dead_start = t
                    if t - dead_start >= t_dead - eps:
                        mode[M_BRIDGE] = -b
                        inhibit = False
                        dead_start = -1.0
                        int_i = 0.0  # the current loop restarts on the new bridge
                # while current flows, fire at the inverter limit to drive it to zero
            else:
                err_i = i_ref - ia_m
                v_ref = kp_i * err_i + int_i + k_nom * if_m * w_m
                ca = b * v_ref / vd0
                lo = math.cos(a_max)
                hi = math.cos(a_min)
                if ca > hi:
                    ca = hi
                elif ca < lo:
                    ca = lo
                else:
                    int_i += ki_i * err_i * t_pulse
                    # discontinuous conduction lowers the loop gain: bound the integrator
                    int_i = min(max(int_i, -0.25 * vd0), 0.25 * vd0)
                alpha = math.acos(ca)
            if fire:
                tf = max(t + alpha / wm_a, last_fire + 1e-6)
                for q in range(Q_FIRE):
                    if fire_t[q] == np.inf:
                        fire_t[q] = tf
                        fire_j[q] = p_next % 6
                        fire_b[q] = mode[M_BRIDGE]
                        break
                last_fire = tf
            p_next += 1
            t_nat = ((p_next * math.pi / 3.0 - math.pi / 6.0) - phi_a) / wm_a
        # ------------------------------------------------ thyristor firings due
        if akind == ARM_THYRISTOR_6P:
            for q in range(Q_FIRE):
                if fire_t[q] <= t + eps:
                    fire_t[q] = np.inf
                    jb = fire_b[q]
                    if jb != mode[M_BRIDGE]:
                        continue  # fired for a bridge that has been changed since
                    jn = int(fire_j[q])
                    if mode[M_ARM_COND] > 0.5:
                        if lc > 0.0:
                            mode[M_OVERLAP] = 1.0
                            mode[M_OLD_PAIR] = mode[M_ARM_PAIR]
                            y[S_Q] = 0.0
                        mode[M_ARM_PAIR] = float(jn)
                    else:
                        _deriv(t, y, k1, raw, motor, fx, arm, fld, filt, mode, tl)
                        e_now = raw[0]  # blocked: the terminal voltage is the back-EMF
                        # the pair turns on only if its voltage drives current its way
                        if jb * (jb * _u_ll(jn, t, amp_a, wm_a, phi_a) - e_now) > 0.0:
                            mode[M_ARM_COND] = 1.0
                            mode[M_ARM_PAIR] = float(jn)
                            mode[M_OVERLAP] = 0.0
        # ------------------------------------------------ chopper: carrier period, PWM edges
        if akind == ARM_CHOPPER:
            if t_car <= t + eps:
                ia_m = y[S_IA] + sig_i * _normal(seed, 3 * tick)
                if_m = y[S_IF] + sig_f * _normal(seed, 3 * tick + 1)
                w_m = fx[12] * y[S_W] + sig_w * _normal(seed, 3 * tick + 2)
                tick += 1
                i_ref, w_ref, int_w = speed_loop(ctrl, t_sw, speed_ref[kprof], w_m, w_ref, int_w)
                err_i = i_ref - ia_m
                v_ref = kp_i * err_i + int_i + k_nom * if_m * w_m
                d = v_ref / amp_a
                if d > 0.98:
                    d = 0.98
                elif d < -0.98:
                    d = -0.98
                else:
                    int_i += ki_i * err_i * t_sw
                _pwm_edges(t_car, t_sw, d, amp_a, sw_t, sw_lv)
                mode[M_ARM_LEVEL] = 0.0
                t_car += t_sw
            for r in range(4):
                if sw_t[r] <= t + eps:
                    mode[M_ARM_LEVEL] = sw_lv[r]
                    sw_t[r] = np.inf
        # ------------------------------------------------ field bridge: natural point, firing
        if (fkind == FLD_BRIDGE_1P or fkind == FLD_HALF_3P) and tf_nat <= t + eps:
            vr = vf_ref[kprof]
            ca = vr / fvd0 if fkind == FLD_BRIDGE_1P else 2.0 * vr / fvd0 - 1.0
            ca = min(max(ca, math.cos(fa_max)), math.cos(fa_min))
            for q in range(Q_FFIRE):
                if ffire_t[q] == np.inf:
                    ffire_t[q] = t + math.acos(ca) / wf
                    if fkind == FLD_BRIDGE_1P:
                        ffire_p[q] = 1.0 if pf_next % 2 == 0 else -1.0
                    else:
                        ffire_p[q] = float(pf_next % 3)
                    break
            pf_next += 1
            tf_nat = (pf_next * f_step + f_off - phf) / wf
        for q in range(Q_FFIRE):
            if ffire_t[q] <= t + eps:
                ffire_t[q] = np.inf
                old = mode[M_FLD_PAIR]
                mode[M_FLD_PAIR] = ffire_p[q]
                if mode[M_FLD_COND] < 0.5:
                    # a blocked bridge conducts again only if the fired pair's voltage is positive
                    if _field_source(t, fld, mode) > 0.0:
                        mode[M_FLD_COND] = 1.0
                    else:
                        mode[M_FLD_PAIR] = old
        if fkind == FLD_CHOPPER:
            if tf_car <= t + eps:
                d = min(max(vf_ref[kprof] / fld[1], -0.98), 0.98)
                _pwm_edges(tf_car, tf_sw, d, fld[1], fsw_t, fsw_lv)
                mode[M_FLD_LEVEL] = 0.0
                tf_car += tf_sw
            for r in range(4):
                if fsw_t[r] <= t + eps:
                    mode[M_FLD_LEVEL] = fsw_lv[r]
                    fsw_t[r] = np.inf
        # ------------------------------------------------ samples due now
        for c in range(5):
            kc = int(ks[c])
            if kc < k_end and kc * dt + delays[c] <= t + eps:
                _deriv(t, y, k1, raw, motor, fx, arm, fld, filt, mode, tl)
                value = _filtered(y, raw, filt, c)
                if averaging[c] > 0.5:
                    z = y[S_ZCH + c]
                    if z_set[c] > 0.5:
                        value = z / dt
                    y[S_ZCH + c] = 0.0
                    z_set[c] = 1.0
                samples[kc - k0, c] = value
                ks[c] = kc + 1
        # ------------------------------------------------ the next event
        t_next = min(t + h_max, t_end)
        if k_next * dt < t_next:
            t_next = k_next * dt
        for c in range(5):
            kc = int(ks[c])
            if kc < k_end:
                ts = kc * dt + delays[c]
                if ts < t_next:
                    t_next = ts
        if akind == ARM_THYRISTOR_6P:
            t_next = min(t_next, t_nat)
            for q in range(Q_FIRE):
                t_next = min(t_next, fire_t[q])
        elif akind == ARM_CHOPPER:
            t_next = min(t_next, t_car)
            for r in range(4):
                t_next = min(t_next, sw_t[r])
        t_next = min(t_next, t_ideal, tf_nat, ffire_t[0], ffire_t[1])
        if fkind == FLD_CHOPPER:
            t_next = min(t_next, tf_car)
            for r in range(4):
                t_next = min(t_next, fsw_t[r])
        h = t_next - t
        if h <= eps:
            # an event that rounding put (just) in the past: take it now
            t = t + 2.0 * eps
            continue
        _rk4(t, y, h, ytmp, k1, k2, k3, k4, raw, motor, fx, arm, fld, filt, mode, tl, ynew)
        if akind == ARM_THYRISTOR_6P and mode[M_ARM_COND] > 0.5:
            b = mode[M_BRIDGE]
            if b * ynew[S_IA] < 0.0:
                # the current reaches zero within the step: the thyristors block there
                frac = y[S_IA] / (y[S_IA] - ynew[S_IA])
                hh = max(h * frac, 0.0)
                _rk4(t, y, hh, ytmp, k1, k2, k3, k4, raw, motor, fx, arm, fld, filt, mode, tl,
                     ynew)  # fmt: skip
                ynew[S_IA] = 0.0
                mode[M_ARM_COND] = 0.0
                mode[M_OVERLAP] = 0.0
                h = hh
            elif mode[M_OVERLAP] > 0.5 and b * (ynew[S_Q] - ynew[S_IA]) >= 0.0:
                # the incoming pair has taken the whole current: the overlap ends
                d0 = y[S_Q] - y[S_IA]
                d1 = ynew[S_Q] - ynew[S_IA]
                frac = d0 / (d0 - d1) if d0 != d1 else 1.0
                hh = min(max(h * frac, 0.0), h)
                _rk4(t, y, hh, ytmp, k1, k2, k3, k4, raw, motor, fx, arm, fld, filt, mode, tl,
                     ynew)  # fmt: skip
                mode[M_OVERLAP] = 0.0
                h = hh
        # field bridges carry current one way only
        if (fkind == FLD_BRIDGE_1P or fkind == FLD_HALF_3P) and ynew[S_IF] < 0.0:
            ynew[S_IF] = 0.0
            mode[M_FLD_COND] = 0.0
        for i in range(N_Y):
            y[i] = ynew[i]
        t = t + h

    state[C_T] = t
    state[C_K] = k_end
    state[C_W_REF], state[C_INT_W], state[C_INT_I] = w_ref, int_w, int_i
    state[C_INHIBIT] = 1.0 if inhibit else 0.0
    state[C_DEAD_START] = dead_start
    state[C_P_NEXT] = p_next
    state[C_T_NAT] = t_nat
    state[C_LAST_FIRE] = last_fire
    state[C_T_CAR] = t_car
    state[C_PF_NEXT] = pf_next
    state[C_TF_NAT] = tf_nat
    state[C_T_QIA] = t_qia
    state[C_TF_CAR] = tf_car
    state[C_T_IDEAL] = t_ideal
    state[C_TICK] = tick
    return samples, truth
