"""The library of candidate physics the diagnosis tests, as composable terms.

Each effect is a named class that declares the signals it needs, its
parameters with physical units and bounds (derived from the recording, so no
motor-specific configuration is needed), the circuits it changes, a one-line
explanation and the equation it adds to the plain model. Effects compose with
``+`` into a :class:`Combination` (the union of their parameters), as
pysindy's feature libraries do. The numeric model they parameterise is the
full vector of :mod:`observer.diagnosis.kernels`: an effect only says which of
its entries it frees, by name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class DataContext:
    """What the bounds of the effects' parameters are derived from.

    Attributes
    ----------
    dt : float
        Sample period (s).
    duration_s : float
    if_peak_a, ia_peak_a, va_peak_v : float
        99th percentiles of ``|if|``, ``|ia|`` and ``|va|``.
    mean_loss_w : float
        Mean copper loss ``Ra*ia^2 + Rf*if^2`` with the baseline resistances (W).
    field_time_constant_s : float
        The baseline's ``Lf/Rf``.
    current_read_after : bool
        The baseline read the armature's current ahead of its voltage by more than a chain's
        filters do (:data:`~observer.diagnosis.diagnose.CHAIN_SHIFT`): currents sampled after
        the voltages, whose ``sampling_skew`` is a negative delay.
    """

    dt: float
    duration_s: float
    if_peak_a: float
    ia_peak_a: float
    va_peak_v: float
    mean_loss_w: float
    field_time_constant_s: float
    current_read_after: bool = False


def thermal_rise(k: float, tau: float, loss_w: float, t: float) -> float:
    """Resistance rise after ``t`` s of a constant cold copper loss, from a cold start.

    With the hot loss ``loss_w*(1 + theta)`` heating the windings,
    ``tau*dtheta/dt = k*loss_w - (1 - k*loss_w)*theta``.

    Parameters
    ----------
    k : float
        Rise per watt (1/W).
    tau : float
        Thermal time constant (s).
    loss_w : float
        Copper loss at the cold resistances (W).
    t : float
        Time (s).

    Returns
    -------
    float
        ``theta(t)``; for ``k*loss_w = 1`` (the edge of runaway) the linear limit.
    """
    g = k * loss_w
    if abs(1.0 - g) < 1e-9:
        return g * t / tau
    return g / (1.0 - g) * (1.0 - math.exp(-(1.0 - g) * t / tau))


@dataclass(frozen=True)
class Parameter:
    """One free parameter of an effect.

    Attributes
    ----------
    name : str
        Entry of :data:`observer.diagnosis.kernels.FULL_PARAMS`.
    unit : str
    low, high : float
        Search bounds.
    neutral : float
        The value at which the effect vanishes (the warm start).
    log : bool
        Search on a logarithmic scale (time constants).
    """

    name: str
    unit: str
    low: float
    high: float
    neutral: float
    log: bool = False


class Effect:
    """A candidate extension of the plain model; subclasses fill in the class attributes."""

    name: str = ""
    explanation: str = ""
    equation: str = ""
    #: Recording channels the effect's model reads.
    signals: tuple[str, ...] = ()
    #: Circuits whose model the effect changes.
    circuits: tuple[str, ...] = ()

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        """Free parameters with bounds for this recording."""
        raise NotImplementedError

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        """Plain-words magnitudes derived from the fitted parameters (e.g. a flux deficit)."""
        return {}

    @property
    def members(self) -> tuple[Effect, ...]:
        return (self,)

    def __add__(self, other: Effect) -> Combination:
        return Combination(self, other)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class Combination(Effect):
    """Two (or more) effects at once: the union of their parameters and circuits."""

    def __init__(self, *effects: Effect) -> None:
        flat: list[Effect] = []
        for e in effects:
            for m in e.members:
                if m.name not in {f.name for f in flat}:
                    flat.append(m)
        self._members = tuple(flat)
        self.name = "+".join(e.name for e in flat)
        self.explanation = "; ".join(e.explanation for e in flat)
        self.equation = "; ".join(e.equation for e in flat)
        self.signals = tuple(dict.fromkeys(s for e in flat for s in e.signals))
        self.circuits = tuple(
            c for c in ("field", "armature") if any(c in e.circuits for e in flat)
        )

    @property
    def members(self) -> tuple[Effect, ...]:
        return self._members

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        seen: dict[str, Parameter] = {}
        for e in self._members:
            for p in e.parameters(ctx):
                seen.setdefault(p.name, p)
        return tuple(seen.values())

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        out: dict[str, float] = {}
        for e in self._members:
            out.update(e.magnitude(values, ctx))
        return out

    def __repr__(self) -> str:
        return " + ".join(repr(e) for e in self._members)


class FieldSaturation(Effect):
    name = "field_saturation"
    explanation = (
        "the field flux is not linear in the field current: the incremental field inductance "
        "falls as the iron saturates, and the EMF constant follows the flux curve"
    )
    equation = (
        "flux g(if) = if/(1 + c|if|): Lf/(1+c|if|)^2 * dif/dt = vf - Rf*if; "
        "va = Ra*ia + La*dia/dt + K*g(if)*omega"
    )
    signals = ("vf", "if", "va", "ia", "omega")
    circuits = ("field", "armature")

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        return (Parameter("saturation_per_a", "1/A", 0.0, 1.0 / ctx.if_peak_a, 0.0),)

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        c = values["saturation_per_a"]
        return {"flux_deficit_at_peak_if": c * ctx.if_peak_a / (1 + c * ctx.if_peak_a)}


class ThermalDrift(Effect):
    name = "thermal_drift"
    explanation = (
        "the winding resistances rise with temperature, driven by the I^2R losses over the "
        "recording"
    )
    equation = (
        "R(t) = R0*(1 + theta), tau*dtheta/dt = k*(Ra0*ia^2 + Rf0*if^2)*(1 + theta) - theta, "
        "theta(0) = 0"
    )
    signals = ("vf", "if", "va", "ia", "omega")
    circuits = ("field", "armature")

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        return (
            Parameter("thermal_rise_per_w", "1/W", 0.0, 1.0 / max(ctx.mean_loss_w, 1e-12), 0.0),
            Parameter(
                "thermal_time_constant_s",
                "s",
                0.2 * ctx.duration_s,
                50.0 * ctx.duration_s,
                2.0 * ctx.duration_s,
                log=True,
            ),  # fmt: skip
        )

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        rise = thermal_rise(
            values["thermal_rise_per_w"], values["thermal_time_constant_s"], ctx.mean_loss_w,
            ctx.duration_s,
        )  # fmt: skip
        return {"resistance_rise_at_end": rise}


class BrushDrop(Effect):
    name = "brush_drop"
    explanation = "a brush contact voltage drop that changes sign with the armature current"
    equation = "va = Ra*ia + La*dia/dt + Vb*tanh(ia/iw) + K*if*omega"
    signals = ("va", "ia", "if", "omega")
    circuits = ("armature",)

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        return (Parameter("brush_drop_v", "V", 0.0, 0.1 * ctx.va_peak_v, 0.0),)


class ArmatureReaction(Effect):
    name = "armature_reaction"
    explanation = "the effective flux falls with the armature current (armature reaction)"
    equation = "va = Ra*ia + La*dia/dt + K*if*(1 - beta*|ia|)*omega"
    signals = ("va", "ia", "if", "omega")
    circuits = ("armature",)

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        # Armature reaction demagnetises: the flux only falls with the current. A flux
        # that seems to rise with it is something else (a speed reading that falls with
        # the load makes the EMF look exactly so), which this effect must not take.
        return (Parameter("reaction_per_a", "1/A", 0.0, 0.3 / ctx.ia_peak_a, 0.0),)

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        return {"flux_loss_at_peak_ia": values["reaction_per_a"] * ctx.ia_peak_a}


class EddyCurrents(Effect):
    name = "eddy_currents"
    explanation = (
        "a shorted eddy-current path coupled to the field winding gives the field a second, "
        "faster time constant"
    )
    equation = (
        "dif/dt + dj/dt = (vf - Rf*if)/Lf; k2*dif/dt + dj/dt = -j/tau_e "
        "(j: eddy current referred to the field)"
    )
    signals = ("vf", "if")
    circuits = ("field",)

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        lo = 3.0 * ctx.dt
        hi = max(0.5 * ctx.field_time_constant_s, 2 * lo)
        return (
            Parameter("eddy_coupling", "-", 0.0, 0.7, 0.0),
            Parameter("eddy_time_constant_s", "s", lo, hi, math.sqrt(lo * hi), log=True),
        )


class SensorOffset(Effect):
    name = "sensor_offset"
    explanation = "a DC offset on a current sensor"
    equation = "ia_measured = ia + offset_a; if_measured = if + offset_f"
    signals = ("vf", "if", "va", "ia", "omega")
    circuits = ("field", "armature")

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        return (
            Parameter("ia_offset_a", "A", -0.1 * ctx.ia_peak_a, 0.1 * ctx.ia_peak_a, 0.0),
            Parameter("if_offset_a", "A", -0.1 * ctx.if_peak_a, 0.1 * ctx.if_peak_a, 0.0),
        )


class SamplingSkew(Effect):
    name = "sampling_skew"
    explanation = "the current channels are sampled with a delay against the voltage channels"
    # A multiplexed ADC reads its channels one after another, in either order: a current
    # read after its voltage (delay < 0) answers the winding's later state. The sign is the
    # one the baseline's relative delay shows (``current_read_after``): free to take both,
    # the delay stood in for other physics (a current offset behind a chopper at 5 kHz was
    # named ``sensor_offset+sampling_skew``, the ideal drive's 1-period skew read 1.36).
    # Where the channels read skewed, a negative delay is the chain's
    # (:func:`~observer.diagnosis.diagnose.decide_verdict`).
    equation = "i_measured[k] = i(t_k - delay)  (delay < 0: the current read after the voltage)"
    signals = ("vf", "if", "va", "ia", "omega")
    circuits = ("field", "armature")

    def parameters(self, ctx: DataContext) -> tuple[Parameter, ...]:
        if ctx.current_read_after:
            return (Parameter("current_delay_s", "s", -1.99 * ctx.dt, 0.0, 0.0),)
        return (Parameter("current_delay_s", "s", 0.0, 1.99 * ctx.dt, 0.0),)

    def magnitude(self, values: dict[str, float], ctx: DataContext) -> dict[str, float]:
        return {"delay_samples": values["current_delay_s"] / ctx.dt}


#: The library, by name, in the order effects are tried.
LIBRARY: dict[str, Effect] = {
    e.name: e
    for e in (
        FieldSaturation(),
        ThermalDrift(),
        BrushDrop(),
        ArmatureReaction(),
        EddyCurrents(),
        SensorOffset(),
        SamplingSkew(),
    )
}


def context_from(rec: Any, field_r: float, field_l: float, arm_r: float) -> DataContext:
    """Bounds context of a recording with the baseline's resistances."""
    ia, i_f = rec["ia"], rec["if"]
    loss = arm_r * ia * ia + field_r * i_f * i_f
    return DataContext(
        dt=rec.dt,
        duration_s=rec.n_samples * rec.dt,
        if_peak_a=float(max(np.percentile(np.abs(i_f), 99), 1e-9)),
        ia_peak_a=float(max(np.percentile(np.abs(ia), 99), 1e-9)),
        va_peak_v=float(max(np.percentile(np.abs(rec["va"]), 99), 1e-9)),
        mean_loss_w=float(np.mean(loss)),
        field_time_constant_s=field_l / field_r,
    )
