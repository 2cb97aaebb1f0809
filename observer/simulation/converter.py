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
channel and a 12-bit ADC. :data:`DEFAULT_PRESET` (``realistic``) is what ``dcobserver simulate``,
the fake drives and the demo recording use.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from observer.config import ConfigError
from observer.estimation.motor import MotorParameters
from observer.simulation.chain import ChannelChain, MeasurementChain, apply_per_channel

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
DEFAULT_PRESET = "realistic"


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


# ------------------------------------------------------------------ drive files


def _sensor_field(help_text: str) -> Any:
    return dataclasses.field(default=None, metadata={"help": help_text})


@dataclass(frozen=True)
class SensorTable:
    """A drive file's ``[sensors.CH]``: what only a simulation knows about a channel.

    ``None`` (left out) keeps the value the preset or ``[sensors]`` gave; the ranges are
    checked by :meth:`observer.simulation.chain.ChannelChain.check`.
    """

    bits: int | None = _sensor_field("ADC resolution, 1-24 bits")
    full_scale: float | None = _sensor_field("bipolar ADC range +-full_scale (V, A or rad/s)")
    noise: float | None = _sensor_field("white noise at the ADC input, fraction of rated")
    gain_error: float | None = _sensor_field("sensor gain error (0.01: reads 1 % high)")
    offset: float | None = _sensor_field("sensor offset (V, A or rad/s)")


@dataclass(frozen=True)
class SensorsTable(SensorTable):
    """A drive file's ``[sensors]``: keys for every channel, a table per channel."""

    va: SensorTable | None = None
    ia: SensorTable | None = None
    vf: SensorTable | None = None
    i_f: SensorTable | None = dataclasses.field(default=None, metadata={"key": "if"})
    omega: SensorTable | None = None


def _sensor_changes(table: SensorTable) -> dict[str, Any]:
    return {
        f.name: getattr(table, f.name)
        for f in dataclasses.fields(SensorTable)
        if getattr(table, f.name) is not None
    }


#: The tables of a drive file besides a dcobserver config's sections (whose [chain] it reads).
DRIVE_TABLES = ("converter", "sensors")


def load_drive_file(path: str | os.PathLike[str], base: DriveSpec) -> DriveSpec:
    """``base`` changed by a drive file: what the file gives, nothing else.

    ``[converter]`` (the fields of :class:`ConverterSpec`), ``[chain]`` (the estimator's
    measurement chain, :class:`observer.config.ChainConfig`: ``[chain.CH]`` with ``filter``,
    ``delay_us``, ``averaging``; ``intersample`` is the estimator's alone) and ``[sensors]``
    (:class:`SensorsTable`). A dcobserver config is a drive file too: its ``[chain]`` is read
    and its other sections are checked and left alone. Example:
    ``config/drive/chain-example.toml``.

    Raises
    ------
    ConfigError
        One line naming the file and the key.
    """
    from observer.config import Config, build, read_toml
    from observer.simulation.chain import CONFIG_FIELDS, front_end_changes

    p = Path(path)
    data = read_toml(p)
    daemon = {f.name for f in dataclasses.fields(Config)}
    unknown = sorted(set(data) - daemon - set(DRIVE_TABLES))
    if unknown:
        raise ConfigError(
            f"{p}: unknown table [{unknown[0]}] (a drive file has [converter], [chain] and "
            "[sensors]; a dcobserver config's sections are read too)"
        )
    source, base_dir = str(p), p.parent
    config = build(
        Config, {k: v for k, v in data.items() if k in daemon}, source=source, base_dir=base_dir
    )
    converter, chain = base.converter, base.chain
    try:
        if "converter" in data:
            table = _table(data, "converter")
            given = build(
                ConverterSpec, table, source=source, base_dir=base_dir, prefix="converter"
            )
            converter = converter.replace(**{k: getattr(given, k) for k in table})
        for name, raw in _table(data, "chain").items():
            if name in CONFIG_FIELDS:  # (intersample is the estimator's alone)
                front_end = getattr(config.chain, CONFIG_FIELDS[name])
                chain = chain.with_channel(name, **front_end_changes(front_end, given=raw))
        if "sensors" in data:
            sensors = build(
                SensorsTable,
                _table(data, "sensors"),
                source=source,
                base_dir=base_dir,
                prefix="sensors",
            )
            changes = {"*": _sensor_changes(sensors)}
            for name, field in CONFIG_FIELDS.items():
                table = getattr(sensors, field)
                if table is not None:
                    changes[name] = _sensor_changes(table)
            chain = apply_per_channel(chain, changes)
    except ConfigError:
        raise
    except ValueError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    return DriveSpec(converter, chain)


def _table(data: Mapping[str, Any], name: str) -> dict[str, Any]:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise ValueError(f"{name}: must be a table [{name}]")
    return table
