"""Physics the plain model leaves out, for simulated recordings that carry it.

The plain model (:mod:`observer.estimation.motor`) is linear: constant resistances, a flux
proportional to the field current, no contact drop. Real machines are not, and
the diagnosis (:mod:`observer.diagnosis.diagnose`) has to be proved on recordings where
each departure is known. This module adds them to the drive simulator:

``field_saturation``
    The field flux follows ``g(if) = if / (1 + c*|if|)`` instead of ``if``: the
    incremental field inductance is ``Lf*g'(if) = Lf/(1 + c*|if|)^2`` and the
    back-EMF and torque use ``K*g(if)``. Magnitude: the flux deficit at rated
    field current, ``c*In/(1 + c*In)``.
``thermal_drift``
    Both winding resistances are ``R0*(1 + theta)``; ``theta`` obeys
    ``tau*dtheta/dt = k*P - theta`` with the copper loss the windings dissipate at
    their present (hot) resistances, ``P = (Ra0*ia^2 + Rf0*if^2)*(1 + theta)`` (W).
    For a constant cold loss ``P0 = Ra0*ia^2 + Rf0*if^2`` that is
    ``tau*dtheta/dt = k*P0 - (1 - k*P0)*theta``: the rise settles at
    ``k*P0/(1 - k*P0)`` with time constant ``tau/(1 - k*P0)`` (and runs away for
    ``k*P0 >= 1``). Magnitude: the steady rise ``m`` at rated currents, so
    ``k = m/((1 + m)*P0_rated)``.
``brush_drop``
    A contact voltage ``Vb*tanh(ia/iw)`` (V) opposes the armature current:
    ``va = Ra*ia + La*dia/dt + Vb*sign(ia) + K*if*omega``.
``armature_reaction``
    The effective flux falls with armature current: ``K*if*(1 - beta*|ia|)``.
    Magnitude: the flux loss at rated armature current, ``beta*Ia_rated``.
``eddy_currents``
    A shorted eddy-current path (time constant ``tau_e``) coupled to the field
    winding with coefficient ``k^2``: a second, faster field time constant.
``sensor_offset``
    A DC offset (A) on the armature current sensor (the recorded signal only).
``sampling_skew``
    The current channels read ``delay`` seconds behind the voltage channels,
    ``i_measured[k] = i(t_k - delay)``: a current sensor's latency, or currents sampled
    before the voltages (the converter drive samples the voltage channels ``delay`` after
    the currents, the same relation). The recorded signals only; the drive sees the true
    currents. Currents sampled *after* the voltages are a chain's per-channel delay
    (``--delay-us ia=...,if=...``).

Two more effects are deliberately *outside* the diagnosis library
(:mod:`observer.diagnosis`): a recording that carries them must come back
``unexplained``, never as the nearest named effect. They need the converter
drive's kernel (:mod:`observer.simulation.converter_kernels`), which tracks the
shaft angle; without ``--converter`` it runs with ideal converters.

``emf_ripple``
    Commutation ripple of the back-EMF, periodic in shaft angle ``phi``:
    ``e = K*if*omega*(1 + eps*cos(N*phi))`` with ``N`` = :data:`EMF_RIPPLE_PER_REV`.
    Magnitude: ``eps``.
``tacho_error``
    A load-dependent speed-sensor error: the recorded speed is
    ``omega*(1 - g*|ia|/Ia_rated)`` (the drive's own controller sees the true
    speed). Magnitude: ``g``, the reading's loss at rated current.

Plant effects are integrated in continuous time (RK4 sub-steps); sensor effects
are applied to the recorded signals.

Besides these, a recording can carry *changes* (:class:`Change`, parsed by
:func:`parse_changes`): at a given time a parameter steps by a relative amount
and stays there (``Ra=+0.03@30``: a loose connection adds 3 % to the armature
resistance 30 s in; ``K=-0.05@60``: a field fault takes 5 % off the EMF
constant), or the tachometer loses part of its reading (``tach=-0.1@40``: from
40 s it reads 10 % low, and the drive's speed loop, which uses it, sees the low
reading too). The tracker's change detection and tachometer cross-check are
proved on such recordings.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from observer.estimation.motor import MotorParameters
from observer.simulation.kernels import drive_controller_step

EFFECT_NAMES = (
    "field_saturation",
    "thermal_drift",
    "brush_drop",
    "armature_reaction",
    "eddy_currents",
    "sensor_offset",
    "sampling_skew",
    "emf_ripple",
    "tacho_error",
)

#: Effects the diagnosis library deliberately does not contain (see the module docstring).
OUTSIDE_LIBRARY = ("emf_ripple", "tacho_error")

#: Back-EMF ripple periods per shaft revolution of ``emf_ripple``.
EMF_RIPPLE_PER_REV = 8

#: Magnitude used when ``--effect NAME`` gives none, in the units of :data:`MAGNITUDE_UNITS`.
DEFAULT_MAGNITUDES: dict[str, float] = {
    "field_saturation": 0.08,
    "thermal_drift": 0.3,
    "brush_drop": 1.0,
    "armature_reaction": 0.05,
    "eddy_currents": 0.2,
    "sensor_offset": 0.01,
    "sampling_skew": 0.5,
    "emf_ripple": 0.02,
    "tacho_error": 0.01,
}

#: What the one number given per effect means.
MAGNITUDE_UNITS: dict[str, str] = {
    "field_saturation": "flux deficit at rated field current (fraction)",
    "thermal_drift": "steady resistance rise at rated currents (fraction)",
    "brush_drop": "brush contact drop (V)",
    "armature_reaction": "flux loss at rated armature current (fraction)",
    "eddy_currents": "coupling k^2 of the eddy path to the field winding (fraction)",
    "sensor_offset": "armature current sensor offset (fraction of rated current)",
    "sampling_skew": "current channels' sampling delay (sample periods)",
    "emf_ripple": f"back-EMF ripple amplitude, {EMF_RIPPLE_PER_REV} per revolution (fraction)",
    "tacho_error": "speed reading's loss at rated armature current (fraction)",
}

#: Thermal time constant of the windings used by the simulator unless told otherwise (s).
THERMAL_TIME_CONSTANT_S = 20.0

#: What a :class:`Change` can step: a winding parameter, or the tachometer's gain.
CHANGE_TARGETS = ("Rf", "Lf", "Ra", "La", "K", "tach")


@dataclass(frozen=True)
class PlantEffects:
    """Physical magnitudes of all effects; zeros are the plain model.

    Attributes
    ----------
    saturation_per_a : float
        ``c`` of ``g(if) = if/(1 + c|if|)`` (1/A).
    thermal_rise_per_w, thermal_time_constant_s : float
        ``k`` (1/W) and ``tau`` (s) of ``tau*dtheta/dt = k*P - theta``, ``P`` the
        copper loss at the hot resistances.
    brush_drop_v, brush_width_a : float
        Contact drop ``Vb*tanh(ia/iw)``: ``Vb`` (V) and ``iw`` (A).
    reaction_per_a : float
        ``beta`` of the flux factor ``1 - beta*|ia|`` (1/A).
    eddy_coupling, eddy_time_constant_s : float
        ``k^2`` (-) and ``tau_e`` (s) of the shorted eddy path.
    ia_offset_a, if_offset_a : float
        DC offsets of the armature and field current sensors (A).
    current_delay_s : float
        How far the current channels read behind the voltages (s): ``i(t_k - delay)``.
    """

    saturation_per_a: float = 0.0
    thermal_rise_per_w: float = 0.0
    thermal_time_constant_s: float = THERMAL_TIME_CONSTANT_S
    brush_drop_v: float = 0.0
    brush_width_a: float = 1.0
    reaction_per_a: float = 0.0
    eddy_coupling: float = 0.0
    eddy_time_constant_s: float = 0.01
    ia_offset_a: float = 0.0
    if_offset_a: float = 0.0
    current_delay_s: float = 0.0

    def plant_array(self) -> np.ndarray:
        """The vector :func:`simulate_drive_effects` takes."""
        return np.array(
            [
                self.saturation_per_a,
                self.thermal_rise_per_w,
                self.thermal_time_constant_s,
                self.brush_drop_v,
                self.brush_width_a,
                self.reaction_per_a,
                self.eddy_coupling,
                self.eddy_time_constant_s,
            ]
        )

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


def parse_effects(text: str) -> dict[str, float]:
    """Parse ``NAME[=MAG][,NAME[=MAG]...]`` into ``{name: magnitude}``.

    Raises
    ------
    ValueError
        Naming the unknown effect or the bad magnitude.
    """
    out: dict[str, float] = {}
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in EFFECT_NAMES:
            raise ValueError(f"unknown effect {name!r}; expected one of {', '.join(EFFECT_NAMES)}")
        if value.strip():
            try:
                mag = float(value)
            except ValueError:
                raise ValueError(f"effect {name}: magnitude {value!r} is not a number") from None
            if not math.isfinite(mag) or mag < 0:
                raise ValueError(f"effect {name}: magnitude must be >= 0, got {value}")
        else:
            mag = DEFAULT_MAGNITUDES[name]
        out[name] = mag
    if not out:
        raise ValueError("no effect named")
    return out


def plant_effects(
    motor: MotorParameters,
    magnitudes: Mapping[str, float],
    dt: float,
    *,
    thermal_time_constant_s: float = THERMAL_TIME_CONSTANT_S,
) -> PlantEffects:
    """Turn relative magnitudes (see :data:`MAGNITUDE_UNITS`) into physical ones for ``motor``.

    ``thermal_time_constant_s`` is the windings' thermal time constant (s) of
    ``thermal_drift``.
    """
    unknown = set(magnitudes) - set(EFFECT_NAMES)
    if unknown:
        raise ValueError(f"unknown effect(s) {sorted(unknown)}")
    if not thermal_time_constant_s > 0:
        raise ValueError(f"thermal time constant must be > 0 s, got {thermal_time_constant_s}")
    kw: dict[str, float] = {
        "brush_width_a": 0.02 * motor.rated_armature_current_a,
        "thermal_time_constant_s": thermal_time_constant_s,
    }
    m = dict(magnitudes)
    if "field_saturation" in m:
        d = m["field_saturation"]
        if not 0 <= d < 0.9:
            raise ValueError(f"field_saturation flux deficit must be in [0, 0.9), got {d}")
        kw["saturation_per_a"] = d / (motor.rated_field_current_a * (1.0 - d))
    if "thermal_drift" in m:
        rated_loss_w = (
            motor.armature_resistance_ohm * motor.rated_armature_current_a**2
            + motor.field_resistance_ohm * motor.rated_field_current_a**2
        )
        # The loss grows with the rise it drives: k*P0*(1 + m) = m at rated currents.
        kw["thermal_rise_per_w"] = m["thermal_drift"] / ((1.0 + m["thermal_drift"]) * rated_loss_w)
    if "brush_drop" in m:
        kw["brush_drop_v"] = m["brush_drop"]
    if "armature_reaction" in m:
        b = m["armature_reaction"]
        if not 0 <= b < 0.5:
            raise ValueError(f"armature_reaction flux loss must be in [0, 0.5), got {b}")
        kw["reaction_per_a"] = b / motor.rated_armature_current_a
    if "eddy_currents" in m:
        k2 = m["eddy_currents"]
        if not 0 <= k2 < 0.9:
            raise ValueError(f"eddy_currents coupling must be in [0, 0.9), got {k2}")
        kw["eddy_coupling"] = k2
        kw["eddy_time_constant_s"] = max(8 * dt, motor.field_time_constant_s / 10.0)
    if "sensor_offset" in m:
        kw["ia_offset_a"] = m["sensor_offset"] * motor.rated_armature_current_a
    if "sampling_skew" in m:
        kw["current_delay_s"] = m["sampling_skew"] * dt
    return PlantEffects(**kw)


@dataclass(frozen=True)
class Change:
    """A step at ``t_s`` (s): ``target`` is multiplied by ``1 + relative`` from then on.

    ``target`` is one of :data:`CHANGE_TARGETS`: a winding parameter (``Ra``,
    ``K``, ...) or ``tach``, the tachometer's gain (``-0.1``: it reads 10 % low).
    """

    target: str
    relative: float
    t_s: float

    def __post_init__(self) -> None:
        if self.target not in CHANGE_TARGETS:
            raise ValueError(
                f"unknown change target {self.target!r}; expected one of "
                f"{', '.join(CHANGE_TARGETS)}"
            )
        if not (math.isfinite(self.relative) and self.relative > -1.0):
            raise ValueError(f"change of {self.target}: relative step must be > -1, got "
                             f"{self.relative}")  # fmt: skip
        if not (math.isfinite(self.t_s) and self.t_s >= 0):
            raise ValueError(f"change of {self.target}: time must be >= 0 s, got {self.t_s}")

    def to_dict(self) -> dict[str, Any]:
        return {"target": self.target, "relative": self.relative, "t_s": self.t_s}


def parse_changes(text: str) -> tuple[Change, ...]:
    """Parse ``TARGET=REL@T[,TARGET=REL@T...]`` (``Ra=+0.03@30,tach=-0.1@40``).

    Raises
    ------
    ValueError
        Naming the item that is not of that form, or the bad target or number.
    """
    out = []
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        target, eq, rest = item.partition("=")
        rel, at, when = rest.partition("@")
        if not (eq and at):
            raise ValueError(f"{item!r} is not TARGET=RELATIVE@SECONDS (e.g. Ra=+0.03@30)")
        try:
            relative, t_s = float(rel), float(when)
        except ValueError:
            raise ValueError(f"{item!r}: RELATIVE and SECONDS must be numbers") from None
        out.append(Change(target.strip(), relative, t_s))
    if not out:
        raise ValueError("no change given")
    return tuple(out)


def change_schedule(changes: Sequence[Change], n: int, dt: float) -> np.ndarray:
    """Per-sample multipliers ``(n, 6)`` of ``Rf, Lf, Ra, La, K`` and the tachometer's gain.

    A change at ``t_s`` acts from the first sample at or after it; several
    changes of one target multiply.
    """
    schedule = np.ones((n, len(CHANGE_TARGETS)))
    for change in changes:
        first = min(n, max(0, math.ceil(change.t_s / dt - 1e-9)))
        schedule[first:, CHANGE_TARGETS.index(change.target)] *= 1.0 + change.relative
    return schedule


def outside_library_array(motor: MotorParameters, magnitudes: Mapping[str, float]) -> np.ndarray:
    """The effects outside the diagnosis library as the converter kernel takes them:
    ``eps, N, g, Ia_rated`` (see the module docstring)."""
    eps = float(magnitudes.get("emf_ripple", 0.0))
    g = float(magnitudes.get("tacho_error", 0.0))
    if not 0 <= eps < 0.5:
        raise ValueError(f"emf_ripple amplitude must be in [0, 0.5), got {eps}")
    if not 0 <= g < 0.5:
        raise ValueError(f"tacho_error must be in [0, 0.5), got {g}")
    return np.array([eps, float(EMF_RIPPLE_PER_REV), g, motor.rated_armature_current_a])


# ------------------------------------------------------------------ plant kernel


@njit(nogil=True, cache=True)
def _derivatives(
    i_f: float,
    j: float,
    ia: float,
    omega: float,
    theta: float,
    vf: float,
    va: float,
    tl: float,
    motor: np.ndarray,
    fx: np.ndarray,
) -> tuple[float, float, float, float, float]:
    rf0, lf, ra0, la, k = motor[0], motor[1], motor[2], motor[3], motor[4]
    inertia, friction = motor[5], motor[6]
    c, kth, tth, vb, iw, beta, k2, te = fx[0], fx[1], fx[2], fx[3], fx[4], fx[5], fx[6], fx[7]
    rf = rf0 * (1.0 + theta)
    ra = ra0 * (1.0 + theta)
    s = 1.0 + c * abs(i_f)
    flux = i_f / s * (1.0 - beta * abs(ia))
    l_inc = lf / (s * s)
    if k2 > 0.0:
        dif = ((vf - rf * i_f) / l_inc + j / te) / (1.0 - k2)
        dj = -j / te - k2 * dif
    else:
        dif = (vf - rf * i_f) / l_inc
        dj = 0.0
    drop = vb * np.tanh(ia / iw) if vb > 0.0 else 0.0
    dia = (va - ra * ia - drop - k * flux * omega) / la
    domega = (k * flux * ia - friction * omega - tl) / inertia
    loss = ra * ia * ia + rf * i_f * i_f  # copper loss at the hot resistances
    dtheta = (kth * loss - theta) / tth if kth > 0.0 else 0.0
    return dif, dj, dia, domega, dtheta


@njit(nogil=True, cache=True)
def simulate_drive_effects(
    dt: float,
    n_sub: int,
    motor: np.ndarray,
    control: np.ndarray,
    speed_ref: np.ndarray,
    torque_load: np.ndarray,
    vf: np.ndarray,
    noise: np.ndarray,
    state0: np.ndarray,
    effects: np.ndarray,
    schedule: np.ndarray,
) -> np.ndarray:
    """The drive of :func:`observer.simulation.kernels.simulate_drive` with a non-ideal plant.

    Same controllers (run once per sample on the noisy measurements, back-EMF
    feed-forward with the nominal ``K``); the plant carries the effects of
    ``effects`` (see :meth:`PlantEffects.plant_array`) and all five states
    (``if``, eddy current ``j``, ``ia``, ``omega``, ``theta``) are integrated
    together by RK4 with ``n_sub`` sub-steps per sample. ``schedule`` (see
    :func:`change_schedule`) multiplies ``Rf, Lf, Ra, La, K`` sample by sample,
    and its last column is the tachometer's gain: the speed the controller
    measures is ``gain * omega`` plus noise.

    Returns
    -------
    true : (n, 6) array
        ``va, ia, vf, if, omega, theta`` at the sample instants, without noise.
    """
    n = speed_ref.shape[0]
    k_emf = motor[4]
    true = np.empty((n, 6))
    i_f, ia, omega = state0[0], state0[1], state0[2]
    j = 0.0
    theta = 0.0
    w_ref = omega
    int_w = 0.0
    int_i = 0.0
    h = dt / n_sub
    plant = motor.copy()
    for k in range(n):
        for p in range(5):
            plant[p] = motor[p] * schedule[k, p]
        ia_m = ia + noise[k, 1]
        if_m = i_f + noise[k, 3]
        w_m = schedule[k, 5] * omega + noise[k, 4]
        va, w_ref, int_w, int_i = drive_controller_step(
            control, k_emf, dt, speed_ref[k], ia_m, if_m, w_m, w_ref, int_w, int_i
        )
        v_field = vf[k]
        true[k, 0] = va
        true[k, 1] = ia
        true[k, 2] = v_field
        true[k, 3] = i_f
        true[k, 4] = omega
        true[k, 5] = theta
        tl = torque_load[k]
        for _ in range(n_sub):
            a1, b1, c1, d1, e1 = _derivatives(
                i_f, j, ia, omega, theta, v_field, va, tl, plant, effects
            )
            a2, b2, c2, d2, e2 = _derivatives(
                i_f + 0.5 * h * a1, j + 0.5 * h * b1, ia + 0.5 * h * c1,
                omega + 0.5 * h * d1, theta + 0.5 * h * e1, v_field, va, tl, plant, effects,
            )  # fmt: skip
            a3, b3, c3, d3, e3 = _derivatives(
                i_f + 0.5 * h * a2, j + 0.5 * h * b2, ia + 0.5 * h * c2,
                omega + 0.5 * h * d2, theta + 0.5 * h * e2, v_field, va, tl, plant, effects,
            )  # fmt: skip
            a4, b4, c4, d4, e4 = _derivatives(
                i_f + h * a3, j + h * b3, ia + h * c3, omega + h * d3, theta + h * e3,
                v_field, va, tl, plant, effects,
            )  # fmt: skip
            i_f += h * (a1 + 2 * a2 + 2 * a3 + a4) / 6
            j += h * (b1 + 2 * b2 + 2 * b3 + b4) / 6
            ia += h * (c1 + 2 * c2 + 2 * c3 + c4) / 6
            omega += h * (d1 + 2 * d2 + 2 * d3 + d4) / 6
            theta += h * (e1 + 2 * e2 + 2 * e3 + e4) / 6
    return true


def delayed(signal: np.ndarray, delay_samples: float) -> np.ndarray:
    """``signal`` read ``delay_samples`` periods late, by cubic (Catmull-Rom) interpolation.

    The first samples, which would need values before the recording, repeat the first value.
    """
    if delay_samples == 0:
        return signal.copy()
    n = signal.size
    pos = np.arange(n) - delay_samples
    k = np.floor(pos).astype(np.int64)
    f = pos - k
    idx = np.clip(np.stack([k - 1, k, k + 1, k + 2]), 0, n - 1)
    p0, p1, p2, p3 = signal[idx]
    return p1 + 0.5 * f * (
        p2 - p0 + f * (2 * p0 - 5 * p1 + 4 * p2 - p3 + f * (3 * (p1 - p2) + p3 - p0))
    )


def effects_metadata(magnitudes: Mapping[str, float], fx: PlantEffects) -> dict[str, Any]:
    """What a recording's metadata says about the effects it carries (the truth for tests)."""
    out: dict[str, Any] = {
        "names": sorted(magnitudes),
        "magnitudes": {k: float(v) for k, v in sorted(magnitudes.items())},
        "units": {k: MAGNITUDE_UNITS[k] for k in sorted(magnitudes)},
        "physical": fx.to_dict(),
    }
    outside = sorted(set(magnitudes) & set(OUTSIDE_LIBRARY))
    if outside:
        if "emf_ripple" in magnitudes:
            out["physical"]["emf_ripple"] = float(magnitudes["emf_ripple"])
            out["physical"]["emf_ripple_per_rev"] = EMF_RIPPLE_PER_REV
        if "tacho_error" in magnitudes:
            out["physical"]["tacho_gain_loss_at_rated_current"] = float(magnitudes["tacho_error"])
        out["outside_library"] = outside
    return out
