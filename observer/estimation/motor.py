"""Separately excited DC machine: parameters and named motors.

The model follows the generalized electrical machine::

    field:      vf = Rf*if + Lf*dif/dt
    armature:   va = Ra*ia + La*dia/dt + K*if*omega
    mechanics:  J*domega/dt = K*if*ia - B*omega - T_load

``K`` is the field-to-armature rotational inductance (V*s/(rad*A) = H): the
back-EMF constant at field current ``if`` is ``K*if`` (V*s/rad).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class MotorParameters:
    """Electromagnetic, mechanical and rated values of a separately excited DC motor.

    All quantities in SI units; the suffix of each name gives the unit.
    """

    field_resistance_ohm: float
    field_inductance_h: float
    armature_resistance_ohm: float
    armature_inductance_h: float
    emf_constant_h: float
    inertia_kgm2: float
    friction_nms: float
    rated_armature_voltage_v: float
    rated_armature_current_a: float
    rated_field_voltage_v: float
    rated_speed_rad_s: float
    name: str = "motor"

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "name":
                continue
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"motor parameter {f.name} must be a positive number, got {value!r}"
                )

    @property
    def rated_field_current_a(self) -> float:
        """Steady field current at rated field voltage (A)."""
        return self.rated_field_voltage_v / self.field_resistance_ohm

    @property
    def field_time_constant_s(self) -> float:
        return self.field_inductance_h / self.field_resistance_ohm

    @property
    def armature_time_constant_s(self) -> float:
        return self.armature_inductance_h / self.armature_resistance_ohm

    @property
    def rated_torque_nm(self) -> float:
        return self.emf_constant_h * self.rated_field_current_a * self.rated_armature_current_a

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MotorParameters:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ValueError(f"unknown motor parameter(s) {unknown}; expected {sorted(names)}")
        return cls(**data)


def _emf_constant(v_rated: float, i_rated: float, r_a: float, speed: float, i_f: float) -> float:
    """K from the rated point: va = Ra*ia + K*if*omega."""
    return (v_rated - r_a * i_rated) / (speed * i_f)


# P-12 (the paper's test motor): Rf, Lf, Ra, La from the paper's table. The
# paper gives no ratings or mechanics; these are plausible for a 220 V machine
# of this size (about 0.6 kW): 220 V, 3 A armature, 220 V field (1.19 A), 1500
# rpm, and a rotor plus coupled load of 0.02 kg*m^2.
P12 = MotorParameters(
    name="P-12",
    field_resistance_ohm=185.0,
    field_inductance_h=50.0,
    armature_resistance_ohm=3.5,
    armature_inductance_h=0.02,
    emf_constant_h=_emf_constant(220.0, 3.0, 3.5, 1500 * 2 * math.pi / 60, 220.0 / 185.0),
    inertia_kgm2=0.02,
    friction_nms=0.001,
    rated_armature_voltage_v=220.0,
    rated_armature_current_a=3.0,
    rated_field_voltage_v=220.0,
    rated_speed_rad_s=1500 * 2 * math.pi / 60,
)

# A 60 V separately excited traction motor (forklift class): 16 mOhm armature,
# 150 A rated, 20 A field. Used to show that estimation needs no motor-specific
# configuration: its values are four orders of magnitude from the P-12's.
TRACTION_60V = MotorParameters(
    name="traction-60V",
    field_resistance_ohm=2.0,
    field_inductance_h=0.3,
    armature_resistance_ohm=0.016,
    armature_inductance_h=0.0002,
    emf_constant_h=_emf_constant(60.0, 150.0, 0.016, 3000 * 2 * math.pi / 60, 20.0),
    inertia_kgm2=0.05,
    friction_nms=0.002,
    rated_armature_voltage_v=60.0,
    rated_armature_current_a=150.0,
    rated_field_voltage_v=40.0,
    rated_speed_rad_s=3000 * 2 * math.pi / 60,
)

# A 440 V, 20 A industrial DC motor (about 8 kW, 1000 rpm) with a 60 mH armature: the second
# converter-fed test motor of the drive-chain work, with R, L and K unlike the P-12's
# (armature time constant 50 ms against 5.7 ms, field 0.2 s against 0.27 s).
INDUSTRIAL_440V = MotorParameters(
    name="industrial-440V",
    field_resistance_ohm=110.0,
    field_inductance_h=22.0,
    armature_resistance_ohm=1.2,
    armature_inductance_h=0.06,
    emf_constant_h=_emf_constant(440.0, 20.0, 1.2, 1000 * 2 * math.pi / 60, 220.0 / 110.0),
    inertia_kgm2=0.5,
    friction_nms=0.01,
    rated_armature_voltage_v=440.0,
    rated_armature_current_a=20.0,
    rated_field_voltage_v=220.0,
    rated_speed_rad_s=1000 * 2 * math.pi / 60,
)

MOTORS: dict[str, MotorParameters] = {
    "p12": P12,
    "traction-60v": TRACTION_60V,
    "industrial-440v": INDUSTRIAL_440V,
}
