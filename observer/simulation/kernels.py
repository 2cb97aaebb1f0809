"""Numba kernels of the simulated plant: a separately excited DC drive under speed control.

These kernels *simulate*; the estimator's kernels (exact discrete winding
models and swarm costs) are :mod:`observer.estimation.kernels`. The plant is
integrated in continuous time (field exactly, armature and mechanics by RK4
sub-steps); the drive's cascade controller (:func:`drive_controller_step`)
runs once per sample on the measured signals, and is shared with the
effects simulator (:mod:`observer.simulation.effects_sim`). The Python objects
that drive these kernels are :mod:`observer.simulation.simulate` and
:mod:`observer.simulation.drive_stream`.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def _armature_mech_rhs(
    ia: float, omega: float, i_f: float, va: float, torque_load: float, motor: np.ndarray
) -> tuple[float, float]:
    ra, la, k, inertia, friction = motor[2], motor[3], motor[4], motor[5], motor[6]
    dia = (va - ra * ia - k * i_f * omega) / la
    domega = (k * i_f * ia - friction * omega - torque_load) / inertia
    return dia, domega


@njit(nogil=True, cache=True)
def speed_loop(
    control: np.ndarray, period: float, speed_ref: float, w_m: float, w_ref: float, int_w: float
) -> tuple[float, float, float]:
    """The speed loop of the drive's cascade, run every ``period`` s: the reference ramped at
    ``ramp``, PI ``kp_w, ki_w`` with the current limit and anti-windup (``control`` as in
    :func:`drive_controller_step`). Returns ``i_ref, w_ref, int_w``."""
    kp_w, ki_w, i_limit, ramp = control[2], control[3], control[4], control[6]
    step = speed_ref - w_ref
    if step > ramp * period:
        step = ramp * period
    elif step < -ramp * period:
        step = -ramp * period
    w_ref += step
    err_w = w_ref - w_m
    i_ref = kp_w * err_w + int_w
    if i_ref > i_limit:
        i_ref = i_limit
    elif i_ref < -i_limit:
        i_ref = -i_limit
    else:
        int_w += ki_w * err_w * period
    return i_ref, w_ref, int_w


@njit(nogil=True, cache=True)
def drive_controller_step(
    control: np.ndarray,
    k_emf: float,
    dt: float,
    speed_ref: float,
    ia_m: float,
    if_m: float,
    w_m: float,
    w_ref: float,
    int_w: float,
    int_i: float,
) -> tuple[float, float, float, float]:
    """One sample of the drive's cascade controller, on measured ``ia, if, omega``.

    Speed loop (ramped reference, PI, current limit, anti-windup) -> current
    reference; current loop (PI with back-EMF feed-forward, voltage limit,
    anti-windup) -> armature voltage held until the next sample. ``control`` is
    ``kp_i, ki_i, kp_w, ki_w, i_limit, v_limit, ramp``. Returns
    ``va, w_ref, int_w, int_i``.
    """
    kp_i, ki_i, v_limit = control[0], control[1], control[5]
    i_ref, w_ref, int_w = speed_loop(control, dt, speed_ref, w_m, w_ref, int_w)
    err_i = i_ref - ia_m
    va = kp_i * err_i + int_i + k_emf * if_m * w_m
    if va > v_limit:
        va = v_limit
    elif va < -v_limit:
        va = -v_limit
    else:
        int_i += ki_i * err_i * dt
    return va, w_ref, int_w, int_i


@njit(nogil=True, cache=True)
def simulate_drive(
    dt: float,
    n_sub: int,
    motor: np.ndarray,
    control: np.ndarray,
    speed_ref: np.ndarray,
    torque_load: np.ndarray,
    vf: np.ndarray,
    noise: np.ndarray,
    state0: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate a speed-controlled, separately excited DC drive.

    The plant is integrated in continuous time: the field exactly (it is linear
    and decoupled), armature and mechanics by RK4 with ``n_sub`` sub-steps per
    sample, with the field current evaluated exactly at each sub-step. The
    drive's controllers run once per sample on the *measured* (noisy) signals
    and hold their voltage until the next sample, as a digital drive does.

    Parameters
    ----------
    motor : (7,) array
        ``Rf, Lf, Ra, La, K, J, B``.
    control : (7,) array
        Current PI ``kp_i, ki_i``; speed PI ``kp_w, ki_w``; armature current
        limit (A); armature voltage limit (V); speed-reference ramp (rad/s^2).
    speed_ref, torque_load, vf : (n,) arrays
        Speed reference (rad/s), load torque (N*m), field voltage (V) per sample.
    noise : (n, 5) array
        Sensor noise added to ``va, ia, vf, if, omega``.
    state0 : (3,) array
        Initial ``if, ia, omega``.

    Returns
    -------
    true, measured : (n, 5) arrays
        ``va, ia, vf, if, omega`` at the sample instants, without and with noise.
    """
    n = speed_ref.shape[0]
    rf, lf, k_emf = motor[0], motor[1], motor[4]
    true = np.empty((n, 5))
    meas = np.empty((n, 5))
    i_f, ia, omega = state0[0], state0[1], state0[2]
    w_ref = omega
    int_w = 0.0
    int_i = 0.0
    h = dt / n_sub
    for k in range(n):
        ia_m = ia + noise[k, 1]
        if_m = i_f + noise[k, 3]
        w_m = omega + noise[k, 4]
        va, w_ref, int_w, int_i = drive_controller_step(
            control, k_emf, dt, speed_ref[k], ia_m, if_m, w_m, w_ref, int_w, int_i
        )
        v_field = vf[k]
        true[k, 0] = va
        true[k, 1] = ia
        true[k, 2] = v_field
        true[k, 3] = i_f
        true[k, 4] = omega
        for c in range(5):
            meas[k, c] = true[k, c] + noise[k, c]
        # Integrate the plant over one sample period with held voltages.
        tl = torque_load[k]
        if_inf = v_field / rf
        for s in range(n_sub):
            a0 = np.exp(-rf * (s * h) / lf)
            a1 = np.exp(-rf * ((s + 0.5) * h) / lf)
            a2 = np.exp(-rf * ((s + 1) * h) / lf)
            f0 = if_inf + (i_f - if_inf) * a0
            f1 = if_inf + (i_f - if_inf) * a1
            f2 = if_inf + (i_f - if_inf) * a2
            k1a, k1w = _armature_mech_rhs(ia, omega, f0, va, tl, motor)
            k2a, k2w = _armature_mech_rhs(
                ia + 0.5 * h * k1a, omega + 0.5 * h * k1w, f1, va, tl, motor
            )
            k3a, k3w = _armature_mech_rhs(
                ia + 0.5 * h * k2a, omega + 0.5 * h * k2w, f1, va, tl, motor
            )
            k4a, k4w = _armature_mech_rhs(ia + h * k3a, omega + h * k3w, f2, va, tl, motor)
            ia += h * (k1a + 2 * k2a + 2 * k3a + k4a) / 6
            omega += h * (k1w + 2 * k2w + 2 * k3w + k4w) / 6
        i_f = if_inf + (i_f - if_inf) * np.exp(-rf * dt / lf)
    return true, meas
