"""Recordings of a DC drive in rope-shovel-like operation.

A hoist motion repeats a dig cycle: dig (high load, low speed, field forced at
the start), hoist (rated speed), hold while the shovel swings, dump (load
drops), and lower at above-base speed with a weakened field, then hold. Each
cycle's durations and levels are drawn around these nominal values, so the
recording carries field forcing/weakening steps, current-limited
accelerations, load steps and current reversals: the excitation the
estimators need. The drive is a speed PI around a current PI with back-EMF
feed-forward, run once per sample on the noisy measurements.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from observer.estimation.motor import P12, MotorParameters
from observer.recording import Recording
from observer.simulation import kernels
from observer.simulation.effects_sim import (
    CHANGE_TARGETS,
    OUTSIDE_LIBRARY,
    THERMAL_TIME_CONSTANT_S,
    Change,
    change_schedule,
)

if TYPE_CHECKING:
    from observer.simulation.converter import DriveSpec

#: Rate (Hz) of the true thermal rise stored in a recording's metadata.
TRUTH_RATE_HZ = 10.0

# (name, duration s, speed / rated, load torque / rated, field voltage / rated)
DUTY_CYCLE: tuple[tuple[str, float, float, float, float], ...] = (
    ("dig", 3.0, 0.4, 1.4, 1.0),
    ("hoist", 2.0, 1.0, 0.9, 1.0),
    ("hold", 1.5, 0.0, 0.9, 1.0),
    ("dump", 0.5, 0.0, 0.3, 1.0),
    ("lower", 2.0, -1.3, 0.3, 0.75),
    ("rest", 1.0, 0.0, 0.3, 0.9),
)

#: Field forcing: after a rise of the field reference, this multiple of the
#: target voltage is applied for ``FORCING_S`` to speed up the field.
FORCING_GAIN = 1.5
FORCING_S = 0.3


@dataclass(frozen=True)
class NoiseLevels:
    """Standard deviation of white sensor noise per channel, in SI units."""

    va: float = 0.0
    ia: float = 0.0
    vf: float = 0.0
    i_f: float = 0.0
    omega: float = 0.0

    @classmethod
    def relative(cls, motor: MotorParameters, fraction: float) -> NoiseLevels:
        """Noise of ``fraction`` of each channel's rated value (0.002 = 0.2 %)."""
        if fraction < 0:
            raise ValueError(f"noise fraction must be >= 0, got {fraction}")
        return cls(
            va=fraction * motor.rated_armature_voltage_v,
            ia=fraction * motor.rated_armature_current_a,
            vf=fraction * motor.rated_field_voltage_v,
            i_f=fraction * motor.rated_field_current_a,
            omega=fraction * motor.rated_speed_rad_s,
        )

    def as_array(self) -> np.ndarray:
        return np.array([self.va, self.ia, self.vf, self.i_f, self.omega])


def duty_cycle_profiles(
    motor: MotorParameters, n: int, dt: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-sample speed reference (rad/s), load torque (N*m) and field voltage (V)."""
    speed = np.empty(n)
    load = np.empty(n)
    field = np.empty(n)
    k = 0
    previous_field = 1.0
    while k < n:
        for _name, duration, speed_pu, load_pu, field_pu in DUTY_CYCLE:
            # Each cycle differs: +-25 % durations, +-15 % levels.
            m = max(1, int(round(duration * rng.uniform(0.75, 1.25) / dt)))
            stop = min(n, k + m)
            speed[k:stop] = speed_pu * rng.uniform(0.85, 1.15) * motor.rated_speed_rad_s
            load[k:stop] = load_pu * rng.uniform(0.85, 1.15) * motor.rated_torque_nm
            target = field_pu * motor.rated_field_voltage_v
            field[k:stop] = target
            if field_pu > previous_field:
                forced = min(stop, k + int(round(FORCING_S / dt)))
                field[k:forced] = FORCING_GAIN * target
            previous_field = field_pu
            k = stop
            if k >= n:
                break
    return speed, load, field


def plant_array(motor: MotorParameters) -> np.ndarray:
    """The motor as :func:`kernels.simulate_drive` takes it: ``Rf, Lf, Ra, La, K, J, B``."""
    return np.array(
        [
            motor.field_resistance_ohm,
            motor.field_inductance_h,
            motor.armature_resistance_ohm,
            motor.armature_inductance_h,
            motor.emf_constant_h,
            motor.inertia_kgm2,
            motor.friction_nms,
        ]
    )


def substeps(motor: MotorParameters, dt: float) -> int:
    """RK4 sub-steps per sample: 50 per armature time constant (error ~1e-9)."""
    return max(1, math.ceil(50 * dt / motor.armature_time_constant_s))


def controller_gains(motor: MotorParameters, dt: float) -> np.ndarray:
    """Gains and limits of the drive's cascade controller (see :func:`kernels.simulate_drive`)."""
    # Current loop: closed-loop time constant a third of the armature's, but
    # not faster than 10 samples; speed loop 8x slower than the current loop.
    from observer.simulation.converter import cascade_gains

    t_current = max(10 * dt, motor.armature_time_constant_s / 3)
    return cascade_gains(motor, t_current)[:7]  # (without the feed-forward constant)


def simulate(
    motor: MotorParameters = P12,
    *,
    duration_s: float = 20.0,
    sample_rate_hz: float = 2000.0,
    noise: NoiseLevels | float = 0.002,
    seed: int | None = 0,
    effects: Mapping[str, float] | None = None,
    changes: Sequence[Change] = (),
    thermal_time_constant_s: float = THERMAL_TIME_CONSTANT_S,
    drive: DriveSpec | None = None,
    drive_name: str | None = None,
) -> Recording:
    """Simulate a recording of ``motor`` in rope-shovel-like operation.

    Parameters
    ----------
    motor : MotorParameters
        The motor; defaults to the paper's P-12.
    duration_s : float
        Length of the recording (s).
    sample_rate_hz : float
        Sample rate (Hz); the drive's controllers run at this rate.
    noise : NoiseLevels or float
        Sensor noise per channel, or one fraction of each channel's rated value.
    seed : int or None
        Seed of the duty-cycle draws and the noise; same seed, same recording.
    effects : mapping of str to float, optional
        Physics the plain model leaves out, by name with a magnitude (see
        :mod:`observer.simulation.effects_sim`), e.g. ``{"brush_drop": 1.0}``. Without it
        the plant is the plain model of :func:`observer.simulation.kernels.simulate_drive`.
    drive : DriveSpec, optional
        Converters and measurement chain (:mod:`observer.simulation.converter`): the recording
        is then made by :func:`observer.simulation.converter_drive.simulate_converter`. Without
        it (and without the effects that need that kernel, ``emf_ripple`` and
        ``tacho_error``) the drive is ideal: voltages held over each sample, no front end.
    drive_name : str, optional
        The preset ``drive`` came from, for the metadata.

    Returns
    -------
    Recording
        Channels ``va, ia, vf, if, omega``; its metadata carries the true motor
        parameters, the noise levels, the seed and (with ``effects``) the
        effects' relative and physical magnitudes under ``"effects"``.
    """
    if not duration_s > 0:
        raise ValueError(f"duration_s must be > 0, got {duration_s}")
    if not sample_rate_hz > 0:
        raise ValueError(f"sample_rate_hz must be > 0, got {sample_rate_hz}")
    levels = noise if isinstance(noise, NoiseLevels) else NoiseLevels.relative(motor, noise)
    if drive is not None or (effects and any(name in effects for name in OUTSIDE_LIBRARY)):
        from observer.simulation.converter import ConverterSpec, DriveSpec
        from observer.simulation.converter_drive import simulate_converter

        if drive is None:
            drive = DriveSpec(ConverterSpec(armature="ideal", field="ideal"))
            drive_name = drive_name or "ideal"
        fractions = noise if not isinstance(noise, NoiseLevels) else noise_fractions(motor, noise)
        rec, _ = simulate_converter(
            motor, drive, duration_s=duration_s, sample_rate_hz=sample_rate_hz,
            noise=fractions, seed=seed, effects=effects, changes=changes,
            thermal_time_constant_s=thermal_time_constant_s, drive_name=drive_name,
        )  # fmt: skip
        return rec
    rng = np.random.default_rng(seed)
    dt = 1.0 / sample_rate_hz
    n = int(round(duration_s * sample_rate_hz))
    if n < 2:
        raise ValueError(f"a recording needs at least 2 samples, got {n}")
    speed, load, field = duty_cycle_profiles(motor, n, dt, rng)
    noise_samples = rng.standard_normal((n, 5)) * levels.as_array()
    n_sub = substeps(motor, dt)
    motor_array = plant_array(motor)
    # Start at rest with the field established, as a drive does after pre-excitation.
    state0 = np.array([field[0] / motor.field_resistance_ohm, 0.0, 0.0])
    fx_meta = None
    thermal = None
    if effects or changes:
        from observer.simulation import effects_sim

        fx = effects_sim.plant_effects(
            motor, effects or {}, dt, thermal_time_constant_s=thermal_time_constant_s
        )
        if fx.eddy_coupling > 0:
            n_sub = max(n_sub, math.ceil(10 * dt / fx.eddy_time_constant_s))
        schedule = change_schedule(changes, n, dt)
        true = effects_sim.simulate_drive_effects(
            dt, n_sub, motor_array, controller_gains(motor, dt),
            speed, load, field, noise_samples, state0, fx.plant_array(), schedule,
        )  # fmt: skip
        measured = true[:, :5] + noise_samples
        measured[:, 4] = schedule[:, 5] * true[:, 4] + noise_samples[:, 4]
        delay = fx.current_delay_s / dt
        if delay:
            for c in (1, 3):
                measured[:, c] = effects_sim.delayed(true[:, c], delay) + noise_samples[:, c]
        measured[:, 1] += fx.ia_offset_a
        measured[:, 3] += fx.if_offset_a
        if effects:
            fx_meta = effects_sim.effects_metadata(effects, fx)
        if fx.thermal_rise_per_w > 0:
            thermal = thermal_truth(true[:, 5], dt)
    else:
        _, measured = kernels.simulate_drive(
            dt, n_sub, motor_array, controller_gains(motor, dt),
            speed, load, field, noise_samples, state0,
        )  # fmt: skip
    t = np.arange(n) * dt
    signals = {
        name: measured[:, c].copy() for c, name in enumerate(("va", "ia", "vf", "if", "omega"))
    }
    metadata: dict[str, Any] = {
        "generator": "dcobserver simulate",
        "motor": motor.to_dict(),
        "noise": {
            "va": levels.va,
            "ia": levels.ia,
            "vf": levels.vf,
            "if": levels.i_f,
            "omega": levels.omega,
        },
        "seed": seed,
        "sample_rate_hz": sample_rate_hz,
    }
    if fx_meta is not None:
        metadata["effects"] = fx_meta
    if changes:
        metadata["changes"] = [c.to_dict() for c in changes]
    if thermal is not None:
        metadata["thermal"] = thermal
    return Recording(t=t, signals=signals, metadata=metadata)


def thermal_truth(theta: np.ndarray, dt: float) -> dict[str, list[float]]:
    """The windings' true relative resistance rise per sample, thinned to
    :data:`TRUTH_RATE_HZ` for a recording's ``"thermal"`` metadata."""
    step = max(1, int(round(1.0 / (dt * TRUTH_RATE_HZ))))
    return {
        "t_s": [round(k * dt, 9) for k in range(0, theta.size, step)],
        "theta": [float(x) for x in theta[::step]],
    }


#: Motor fields of the parameters :func:`true_parameters` returns.
_PARAMETER_FIELDS = {
    "Rf": "field_resistance_ohm",
    "Lf": "field_inductance_h",
    "Ra": "armature_resistance_ohm",
    "La": "armature_inductance_h",
    "K": "emf_constant_h",
}


def true_parameters(metadata: Mapping[str, Any], t_s: np.ndarray) -> dict[str, np.ndarray]:
    """The true parameters of a simulated recording at the times ``t_s`` (s), from its metadata.

    Returns
    -------
    dict
        ``Rf, Lf, Ra, La, K`` (the motor's values, stepped by the recording's
        ``changes`` and raised by its thermal rise), ``tach`` (the tachometer's
        gain) and ``theta`` (the windings' relative resistance rise), each an
        array like ``t_s``.

    Raises
    ------
    KeyError
        If ``metadata`` has no ``motor`` (not a simulated recording).
    """
    t = np.asarray(t_s, dtype=float)
    motor = metadata["motor"]
    out = {name: np.full(t.shape, float(motor[key])) for name, key in _PARAMETER_FIELDS.items()}
    out["tach"] = np.ones(t.shape)
    for change in metadata.get("changes", ()):
        out[change["target"]] *= np.where(t >= change["t_s"], 1.0 + change["relative"], 1.0)
    thermal = metadata.get("thermal")
    theta = np.interp(t, thermal["t_s"], thermal["theta"]) if thermal else np.zeros(t.shape)
    out["Rf"] *= 1.0 + theta
    out["Ra"] *= 1.0 + theta
    out["theta"] = theta
    assert set(out) == {*CHANGE_TARGETS, "theta"}
    return out


def noise_fractions(motor: MotorParameters, levels: NoiseLevels) -> dict[str, float]:
    """Per-channel noise levels (SI) as fractions of the rated values."""
    rated = (
        motor.rated_armature_voltage_v,
        motor.rated_armature_current_a,
        motor.rated_field_voltage_v,
        motor.rated_field_current_a,
        motor.rated_speed_rad_s,
    )
    return {
        name: float(level / r)
        for name, level, r in zip(("va", "ia", "vf", "if", "omega"), levels.as_array(), rated,
                                  strict=True)
    }  # fmt: skip
