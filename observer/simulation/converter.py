"""The drive around the motor: which converters feed it, how they are sized and controlled, and
the measurement chain that records it (:class:`DriveSpec`), with named presets.

:class:`ConverterSpec` says what the user chose (kinds, mains, supply voltages, dead time);
:func:`size_converter` turns it into the numbers the kernel
(:mod:`observer.simulation.converter_kernels`) takes, sizing what was left open from the motor's
ratings: the armature bridge's line voltage so that 1.35*V_LL*cos(15 deg) = 1.15*Va_rated, the
field bridge's supply so that it reaches the 1.5x field forcing at 15 deg, a chopper's DC link
at 1.2x (armature) or 1.6x (field) the rated voltage. Equations: ``docs/drive_chain.md``.

Presets (:data:`PRESETS`): ``ideal`` is today's simulator (voltages held per sample, no front
end: ``None``), ``realistic`` what users have: a dual 6-pulse thyristor bridge on 50 Hz mains,
a single-phase field bridge, a 2nd-order Butterworth anti-aliasing filter at fs/4 on every
channel and a 12-bit ADC. :data:`DEFAULT_PRESET` is what ``dcobserver simulate``, the fake drives
and the demo recording use.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from observer.config import ConfigError
from observer.estimation.motor import MotorParameters
from observer.simulation.chain import (
    CHANNELS,
    ChannelChain,
    MeasurementChain,
    apply_per_channel,
    parse_filter,
)

# (numba is imported only to size a converter, so that ``dcobserver --help`` stays fast)
ARMATURE_KINDS: tuple[str, ...] = ("ideal", "thyristor-6p", "chopper")
FIELD_KINDS: tuple[str, ...] = ("ideal", "bridge-1p", "half-3p", "chopper")


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


#: Firing-angle limits of the field bridges (deg): (single-phase, half-controlled 3-phase).
FIELD_ALPHA_DEG = {"bridge-1p": (5.0, 170.0), "half-3p": (5.0, 175.0)}
#: The firing angle at which a sized converter reaches its target voltage (deg).
SIZING_ALPHA_DEG = 15.0


@dataclass(frozen=True)
class ConverterSpec:
    """The armature and field converters; ``None`` voltages are sized from the motor.

    Attributes
    ----------
    armature : str
        ``ideal`` (held per sample), ``thyristor-6p`` (dual 6-pulse bridge, circulating-current
        free) or ``chopper`` (4-quadrant H-bridge, unipolar PWM).
    field : str
        ``ideal``, ``bridge-1p`` (single-phase fully controlled), ``half-3p`` (3-phase
        half-controlled with freewheeling diode) or ``chopper``.
    mains_hz : float
        Mains frequency of the bridges (Hz).
    line_voltage_v : float or None
        RMS line-to-line voltage feeding the armature bridge (V).
    field_supply_v : float or None
        RMS supply of the field bridge (V; line-to-line for ``half-3p``), or the field chopper's
        DC link.
    dc_link_v : float or None
        DC link of the armature chopper (V).
    source_inductance_h : float
        Commutating inductance per phase (H); 0: instantaneous commutation, > 0: overlap.
        For the chopper an inductance in series with the armature.
    switching_hz : float
        PWM carrier frequency of the choppers (Hz); the output pulses at twice this.
    dead_time_s : float
        Dead time of a bridge changeover, counted from zero current (s).
    alpha_min_deg, alpha_max_deg : float
        Firing-angle limits of the armature bridge (deg): rectifier and inverter limit.
    """

    armature: str = "thyristor-6p"
    field: str = "bridge-1p"
    mains_hz: float = 50.0
    line_voltage_v: float | None = None
    field_supply_v: float | None = None
    dc_link_v: float | None = None
    source_inductance_h: float = 0.0
    switching_hz: float = 2000.0
    dead_time_s: float = 0.002
    alpha_min_deg: float = 5.0
    alpha_max_deg: float = 150.0

    def __post_init__(self) -> None:
        if self.armature not in ARMATURE_KINDS:
            raise ValueError(
                f"converter.armature: unknown converter {self.armature!r} "
                f"(expected {', '.join(ARMATURE_KINDS)})"
            )
        if self.field not in FIELD_KINDS:
            raise ValueError(
                f"converter.field: unknown field converter {self.field!r} "
                f"(expected {', '.join(FIELD_KINDS)})"
            )
        for name in ("mains_hz", "switching_hz"):
            value = getattr(self, name)
            if not _number(value) or not 1.0 <= value <= 100_000.0:
                raise ValueError(f"converter.{name}: must be 1..100000 Hz, got {value!r}")
        for name in ("line_voltage_v", "field_supply_v", "dc_link_v"):
            value = getattr(self, name)
            if value is not None and not (_number(value) and value > 0):
                raise ValueError(f"converter.{name}: must be > 0, got {value!r}")
        if not (_number(self.source_inductance_h) and self.source_inductance_h >= 0):
            raise ValueError(
                f"converter.source_inductance_h: must be >= 0, got {self.source_inductance_h!r}"
            )
        if not (_number(self.dead_time_s) and 0 <= self.dead_time_s <= 0.05):
            raise ValueError(f"converter.dead_time_s: must be 0..0.05 s, got {self.dead_time_s!r}")
        lo, hi = self.alpha_min_deg, self.alpha_max_deg
        if not (_number(lo) and _number(hi) and 0 <= lo < 90 < hi < 180):
            raise ValueError(
                "converter.alpha_min_deg/alpha_max_deg: need 0 <= min < 90 < max < 180, "
                f"got {lo!r}, {hi!r}"
            )

    def replace(self, **changes: Any) -> ConverterSpec:
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class DriveSpec:
    """A converter-fed drive and its measurement chain (see the module docstring)."""

    converter: ConverterSpec = ConverterSpec()
    chain: MeasurementChain = MeasurementChain()

    def replace(self, **changes: Any) -> DriveSpec:
        return dataclasses.replace(self, **changes)


#: The realistic front end: 2nd-order Butterworth at fs/4 and a 12-bit ADC on every channel;
#: noise is the recording's (0.2 % of rated by default).
REALISTIC_CHANNEL = ChannelChain(filter="butter", order=2, cutoff_per_fs=0.25, bits=12)

#: Named drives; ``None`` is the ideal drive of :func:`observer.simulation.simulate.simulate`.
PRESETS: dict[str, DriveSpec | None] = {
    "ideal": None,
    "realistic": DriveSpec(
        ConverterSpec(armature="thyristor-6p", field="bridge-1p"),
        MeasurementChain.uniform(REALISTIC_CHANNEL),
    ),
}

#: The preset of ``dcobserver simulate``, ``dcobserver fake-drive`` and the demo recording.
DEFAULT_PRESET = "ideal"


@dataclass(frozen=True)
class ConverterSetup:
    """A :class:`ConverterSpec` sized for one motor and sample rate: the kernel's arrays.

    Attributes
    ----------
    arm, fld, ctrl : arrays
        As :func:`observer.simulation.converter_kernels.advance` takes them.
    full_scale, rated : dict of str to float
        Default ADC full scale and rated value per channel (SI).
    metadata : dict
        What the recording says about the converter and its controller.
    """

    arm: np.ndarray
    fld: np.ndarray
    ctrl: np.ndarray
    full_scale: dict[str, float]
    rated: dict[str, float]
    metadata: dict[str, Any]


def cascade_gains(motor: MotorParameters, t_current: float) -> np.ndarray:
    """Cascade controller for a closed current loop of time constant ``t_current`` (s).

    Current PI ``La/Tc, Ra/Tc`` (pole-zero cancellation), speed PI 8x slower, current limit 2x
    rated, voltage limit 1.15x rated, speed ramp to rated in 0.5 s, and the back-EMF
    feed-forward constant ``K``: ``kp_i, ki_i, kp_w, ki_w, i_limit, v_limit, ramp, K``.
    """
    t_speed = 8 * t_current
    flux = motor.emf_constant_h * motor.rated_field_current_a
    kp_w = motor.inertia_kgm2 / (flux * t_speed)
    return np.array(
        [
            motor.armature_inductance_h / t_current,
            motor.armature_resistance_ohm / t_current,
            kp_w,
            kp_w / (4 * t_speed),
            2.0 * motor.rated_armature_current_a,
            1.15 * motor.rated_armature_voltage_v,
            motor.rated_speed_rad_s / 0.5,
            motor.emf_constant_h,
        ]
    )


def size_converter(
    spec: ConverterSpec,
    motor: MotorParameters,
    sample_rate_hz: float,
    rng: np.random.Generator,
) -> ConverterSetup:
    """Size ``spec`` for ``motor``; mains and carrier phases are drawn from ``rng``."""
    from observer.simulation import converter_kernels as ck

    dt = 1.0 / sample_rate_hz
    wm = 2 * math.pi * spec.mains_hz
    cos_sizing = math.cos(math.radians(SIZING_ALPHA_DEG))
    tau_a = motor.armature_time_constant_s
    phase_a = float(rng.uniform(0, 2 * math.pi))
    phase_f = float(rng.uniform(0, 2 * math.pi))
    arm_meta: dict[str, Any] = {"kind": spec.armature}
    if spec.armature == "thyristor-6p":
        v_ll = spec.line_voltage_v or 1.15 * motor.rated_armature_voltage_v / (1.35 * cos_sizing)
        amp = math.sqrt(2) * v_ll
        arm = np.array(
            [ck.ARM_THYRISTOR_6P, amp, wm, phase_a, spec.source_inductance_h,
             math.radians(spec.alpha_min_deg), math.radians(spec.alpha_max_deg),
             spec.dead_time_s, 0.02 * motor.rated_armature_current_a]
        )  # fmt: skip
        va_fs = 1.1 * amp
        t_current = max(3 / (6 * spec.mains_hz), tau_a / 2)
        arm_meta |= {
            "mains_hz": spec.mains_hz,
            "line_voltage_v": v_ll,
            "no_load_voltage_v": 3 * amp / math.pi,
            "source_inductance_h": spec.source_inductance_h,
            "dead_time_s": spec.dead_time_s,
            "alpha_min_deg": spec.alpha_min_deg,
            "alpha_max_deg": spec.alpha_max_deg,
            "pulses_per_period": 6,
        }
    elif spec.armature == "chopper":
        vdc = spec.dc_link_v or 1.2 * motor.rated_armature_voltage_v
        arm = np.array([ck.ARM_CHOPPER, vdc, spec.switching_hz, phase_a,
                        spec.source_inductance_h, 0.0, 0.0, 0.0, 0.0])  # fmt: skip
        va_fs = 1.1 * vdc
        t_current = max(5 / spec.switching_hz, tau_a / 3)
        arm_meta |= {
            "dc_link_v": vdc,
            "switching_hz": spec.switching_hz,
            "pwm": "unipolar, centred",
            "series_inductance_h": spec.source_inductance_h,
        }
    else:
        arm = np.array([ck.ARM_IDEAL, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        va_fs = 1.5 * motor.rated_armature_voltage_v
        t_current = max(10 * dt, tau_a / 3)
        arm_meta |= {"held": "per sample"}
    vf_rated = motor.rated_field_voltage_v
    fld_meta: dict[str, Any] = {"kind": spec.field}
    if spec.field == "bridge-1p":
        vs = spec.field_supply_v or 1.5 * vf_rated / (0.9 * cos_sizing)
        lo, hi = FIELD_ALPHA_DEG["bridge-1p"]
        fld = np.array([ck.FLD_BRIDGE_1P, math.sqrt(2) * vs, wm, phase_f, math.radians(lo),
                        math.radians(hi), 0.9 * vs])  # fmt: skip
        vf_fs = 1.1 * math.sqrt(2) * vs
        fld_meta |= {"mains_hz": spec.mains_hz, "supply_v": vs, "no_load_voltage_v": 0.9 * vs}
    elif spec.field == "half-3p":
        vll = spec.field_supply_v or 1.5 * vf_rated / (1.35 * cos_sizing)
        lo, hi = FIELD_ALPHA_DEG["half-3p"]
        fld = np.array([ck.FLD_HALF_3P, math.sqrt(2) * vll / math.sqrt(3), wm, phase_f,
                        math.radians(lo), math.radians(hi), 1.35 * vll])  # fmt: skip
        vf_fs = 1.1 * math.sqrt(2) * vll
        fld_meta |= {
            "mains_hz": spec.mains_hz, "line_voltage_v": vll, "no_load_voltage_v": 1.35 * vll,
        }  # fmt: skip
    elif spec.field == "chopper":
        vdc = spec.field_supply_v or 1.6 * vf_rated
        fld = np.array([ck.FLD_CHOPPER, vdc, spec.switching_hz, phase_f, 0.0, 0.0, 0.0])
        vf_fs = 1.1 * vdc
        fld_meta |= {"dc_link_v": vdc, "switching_hz": spec.switching_hz}
    else:
        fld = np.array([ck.FLD_IDEAL, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
        vf_fs = 2.0 * vf_rated
        fld_meta |= {"held": "per sample"}
    ctrl = cascade_gains(motor, t_current)
    rated = {
        "va": motor.rated_armature_voltage_v,
        "ia": motor.rated_armature_current_a,
        "vf": vf_rated,
        "if": motor.rated_field_current_a,
        "omega": motor.rated_speed_rad_s,
    }
    full_scale = {
        "va": va_fs,
        "ia": 4.0 * motor.rated_armature_current_a,
        "vf": vf_fs,
        "if": 2.0 * motor.rated_field_current_a,
        "omega": 2.0 * motor.rated_speed_rad_s,
    }
    names = ("kp_i", "ki_i", "kp_w", "ki_w", "i_limit_a", "v_limit_v", "ramp_rad_s2", "k_ff_h")
    controller: dict[str, Any] = {name: float(v) for name, v in zip(names, ctrl, strict=True)}
    controller["current_loop_time_constant_s"] = t_current
    controller["runs"] = {
        "thyristor-6p": "at each natural commutation point (6x mains), firing angle set once "
        "per pulse",
        "chopper": "once per PWM carrier period",
        "ideal": "once per sample",
    }[spec.armature]
    metadata = {"armature": arm_meta, "field": fld_meta, "controller": controller}
    return ConverterSetup(arm, fld, ctrl, full_scale, rated, metadata)


# ------------------------------------------------------------------ files and options

_CHANNEL_KEYS = ("filter", "delay_s", "gain_error", "offset", "bits", "full_scale", "noise",
                 "averaging")  # fmt: skip


def channel_changes(key: str, value: Any, where: str) -> dict[str, Any]:
    """One chain key and its value (from TOML or an option) -> :class:`ChannelChain` fields.

    ``filter`` takes the option syntax (``butter2@fs/4``); the rest are the fields themselves.
    Raises :class:`ValueError` naming ``where.key``.
    """
    if key == "filter":
        if not isinstance(value, str):
            raise ValueError(f"{where}.filter: must be a string like 'butter2@fs/4'")
        try:
            return parse_filter(value)
        except ValueError as exc:
            raise ValueError(f"{where}.filter: {exc}") from None
    if key == "averaging":
        if not isinstance(value, bool):
            raise ValueError(f"{where}.averaging: must be true or false, got {value!r}")
        return {"averaging": value}
    if key == "bits":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{where}.bits: must be an integer, got {value!r}")
        return {"bits": value}
    if key in _CHANNEL_KEYS:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{where}.{key}: must be a number, got {value!r}")
        return {key: float(value)}
    raise ValueError(f"{where}: unknown key {key!r} (allowed: {', '.join(_CHANNEL_KEYS)})")


def apply_chain_table(chain: MeasurementChain, table: Mapping[str, Any]) -> MeasurementChain:
    """``chain`` changed by a ``[chain]`` table: keys for every channel, sub-tables per channel.

    Raises :class:`ValueError` naming ``chain.KEY`` or ``chain.CHANNEL.KEY``.
    """
    changes: dict[str, dict[str, Any]] = {}
    for key, value in table.items():
        if key in CHANNELS:
            if not isinstance(value, Mapping):
                raise ValueError(f"chain.{key}: must be a table [chain.{key}]")
            per: dict[str, Any] = {}
            for k, v in value.items():
                per |= channel_changes(k, v, f"chain.{key}")
            changes[key] = per
        elif key in _CHANNEL_KEYS:
            changes.setdefault("*", {}).update(channel_changes(key, value, "chain"))
        else:
            raise ValueError(
                f"chain: unknown key {key!r} (allowed: {', '.join(_CHANNEL_KEYS)}, "
                f"or a table per channel: {', '.join(CHANNELS)})"
            )
    return apply_per_channel(chain, changes)


def apply_converter_table(spec: ConverterSpec, table: Mapping[str, Any]) -> ConverterSpec:
    """``spec`` changed by a ``[converter]`` table (keys: the fields of :class:`ConverterSpec`)."""
    fields = {f.name for f in dataclasses.fields(ConverterSpec)}
    for key, value in table.items():
        if key not in fields:
            raise ValueError(
                f"converter: unknown key {key!r} (allowed: {', '.join(sorted(fields))})"
            )
        expect_str = key in ("armature", "field")
        if expect_str != isinstance(value, str) or isinstance(value, bool):
            kind = "a string" if expect_str else "a number"
            raise ValueError(f"converter.{key}: must be {kind}, got {value!r}")
    return dataclasses.replace(spec, **dict(table))


def load_drive_file(path: str | os.PathLike[str], base: DriveSpec) -> DriveSpec:
    """``base`` changed by a TOML file with ``[converter]`` and/or ``[chain]`` tables.

    Raises
    ------
    ConfigError
        One line naming the file and the key.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{p}: file not found") from None
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    unknown = sorted(set(data) - {"converter", "chain"})
    if unknown:
        raise ConfigError(f"{p}: unknown table [{unknown[0]}] (allowed: [converter], [chain])")
    try:
        converter = base.converter
        if "converter" in data:
            if not isinstance(data["converter"], dict):
                raise ValueError("converter: must be a table [converter]")
            converter = apply_converter_table(converter, data["converter"])
        chain = base.chain
        if "chain" in data:
            if not isinstance(data["chain"], dict):
                raise ValueError("chain: must be a table [chain]")
            chain = apply_chain_table(chain, data["chain"])
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return DriveSpec(converter, chain)
