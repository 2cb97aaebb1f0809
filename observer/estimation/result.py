"""The estimate of one winding, as every estimator returns it."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from observer.estimation.pso import PSOResult
from observer.estimation.ranges import SearchRange


@dataclass(frozen=True)
class CircuitEstimate:
    """Estimated parameters of one winding.

    Attributes
    ----------
    circuit : {"field", "armature"}
    resistance_ohm, inductance_h : float
    emf_constant_h : float or None
        ``K`` of ``K*if*omega`` (armature only; V*s/(rad*A)).
    initial_current_a : float
        Fitted current at the window's first sample.
    rms_a : float
        Root-mean-square current error of the fit (A).
    std : dict
        One-sigma uncertainty per parameter (``R``, ``L``, ``K``): the Cramer-Rao
        bound from the Fisher information at the optimum with the fit's residual
        variance; for the armature combined with the size of the errors-in-variables
        correction (the bound alone ignores noise on the measured voltages).
    n_samples : int
    search_range : SearchRange
    pso : PSOResult
        The swarm search (its ``x`` is ``log10 (R, L)``).
    polished : bool
        Whether Levenberg-Marquardt refined the swarm's best.
    input_noise_var : float
        Variance (V^2) of white noise on the model's input voltage found in the
        residual and compensated (0: none found, or compensation off).
    describes_window : bool
        False when the model cannot describe this window (e.g. the voltage
        between samples is not known well enough): the values are then not
        evidence about the motor, whatever their ``std``, and must not be used.
    note : str
        Why ``describes_window`` is False (empty otherwise).
    intersample : {"hold", "smooth", "switched"}
        The voltage's intersample model used (see :mod:`observer.estimation.intersample`).
    shift_samples, shift_std : float
        Fitted delay of the voltage channel behind the current channel, and its
        one-sigma uncertainty (sample periods; 0 and 0 when not fitted).
    coverage : float
        Share of the window's samples inside segments (1 unless ``switched``).
    front_end_std : float
        The part of ``std["L"]`` (H) an unknown mismatch of the voltage and current
        channels' front ends leaves (0 where they are configured; see
        :func:`~observer.estimation.frontend.unknown_mismatch`).
    mismatch_size, mismatch_shift : float
        Untold front ends: the size of the commonest mismatch of the channels
        (:data:`~observer.estimation.frontend.UNKNOWN_MISMATCH`) this window measured,
        relative to its raw voltage, and the voltage's delay (sample periods) that goes
        with it; what the daemon learns the chain from (NaN: not measured).
    shared_std : dict
        The part of ``std`` per parameter (same units) that every window at the same
        operating point shares: a bias that averaging windows does not shrink (the
        voltage sensor's offset, the alias of converter jumps locked to the samples;
        :func:`~observer.estimation.stages.std_stage`). Empty: none known.
    voltage_filter : dict or None
        Untold front ends: the voltage channel's filter as the converter's jumps showed it
        (:meth:`~observer.estimation.filter_id.FilterFit.to_dict`, with its ``text`` in the
        ``[chain]`` grammar; ``alias`` None: not identified, the weakest filter in use
        assumed). None: not tried (configured front ends, a held voltage, a single window).
    voltage_linearity : dict or None
        Whether the voltage reading is linear in the voltage over the recording
        (:meth:`~observer.estimation.linearity.Linearity.to_dict`; a converter's pulses
        sampled in step with the ADC read as a curve). None: not tested (the field, whose
        voltage follows its current; a recording too short).
    operating_point_std : dict
        The part of ``std`` per parameter (same units) that the fits over the recording's low-
        and high-voltage halves found (:func:`~observer.estimation.stages.operating_point_stage`:
        a reading whose error depends on the operating point). Empty: not tested.
    """

    circuit: str
    resistance_ohm: float
    inductance_h: float
    emf_constant_h: float | None
    initial_current_a: float
    rms_a: float
    std: Mapping[str, float]
    n_samples: int
    search_range: SearchRange
    pso: PSOResult = field(repr=False)
    polished: bool = True
    input_noise_var: float = 0.0
    describes_window: bool = True
    note: str = ""
    intersample: str = "hold"
    shift_samples: float = 0.0
    shift_std: float = 0.0
    coverage: float = 1.0
    front_end_std: float = 0.0
    shared_std: Mapping[str, float] = field(default_factory=dict)
    mismatch_size: float = math.nan
    mismatch_shift: float = math.nan
    voltage_filter: Mapping[str, object] | None = None
    voltage_linearity: Mapping[str, object] | None = None
    operating_point_std: Mapping[str, float] = field(default_factory=dict)

    @property
    def time_constant_s(self) -> float:
        return self.inductance_h / self.resistance_ohm

    def value(self, name: str) -> float | None:
        """The estimate of ``"R"``, ``"L"`` or ``"K"`` (None: K not estimated)."""
        return {"R": self.resistance_ohm, "L": self.inductance_h, "K": self.emf_constant_h}[name]

    def relative_std(self, name: str) -> float:
        """``std[name] / |value|``: e.g. > 0.05 means the window hardly identifies it."""
        value = self.value(name)
        if value is None or value == 0:
            return math.inf
        return self.std[name] / abs(value)

    def relative_shared_std(self, name: str) -> float:
        """``shared_std[name] / |value|`` (0 where none is known)."""
        value = self.value(name)
        shared = self.shared_std.get(name, 0.0)
        if value is None or value == 0 or shared == 0:
            return 0.0
        return shared / abs(value)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: ``R, L, (K), rms, std, rel_std, ...``."""
        out: dict[str, Any] = {"R": self.resistance_ohm, "L": self.inductance_h}
        if self.emf_constant_h is not None:
            out["K"] = self.emf_constant_h
        out["tau"] = self.time_constant_s
        out["rms"] = self.rms_a
        out["std"] = dict(self.std)
        out["rel_std"] = {name: self.relative_std(name) for name in self.std}
        out["i0"] = self.initial_current_a
        out["n_samples"] = self.n_samples
        out["input_noise_var"] = self.input_noise_var
        out["describes_window"] = self.describes_window
        out["intersample"] = self.intersample
        out["shift_samples"] = self.shift_samples
        out["shift_std"] = self.shift_std
        out["coverage"] = self.coverage
        out["front_end_std"] = self.front_end_std
        if self.shared_std:
            out["shared_std"] = dict(self.shared_std)
        if self.note:
            out["note"] = self.note
        if self.voltage_filter is not None:
            out["voltage_filter"] = dict(self.voltage_filter)
        if self.voltage_linearity is not None:
            out["voltage_linearity"] = dict(self.voltage_linearity)
        if self.operating_point_std:
            out["operating_point_std"] = dict(self.operating_point_std)
        out["iterations"] = self.pso.n_iterations
        out["evaluations"] = self.pso.n_evaluations
        out["search_range"] = {
            "R": list(self.search_range.resistance_ohm),
            "L": list(self.search_range.inductance_h),
        }
        return out


def kphi(emf_constant_h: float, std_h: float, field_current_a: float) -> tuple[float, float]:
    """kPhi = K*if (V*s/rad): the EMF constant at field current ``field_current_a``, the figure
    a motor's data sheet gives, and its one-sigma from K's (the field current's own error, a
    sensor's fraction of a percent, left out)."""
    return emf_constant_h * field_current_a, abs(std_h * field_current_a)


def with_gain_tolerance(est: CircuitEstimate, rel: Mapping[str, float]) -> CircuitEstimate:
    """``est`` with each parameter's relative one-sigma ``rel[name]`` (a sensor's gain
    accuracy, :func:`observer.estimation.frontend.gain_tolerances`) added to its ``std`` and
    to the part every window shares (``shared_std``): a bias no weighing of windows removes."""
    if not rel:
        return est
    std, shared = dict(est.std), dict(est.shared_std)
    for name, r in rel.items():
        value = est.value(name)
        if r <= 0 or name not in std or value is None or not math.isfinite(value):
            continue
        bias = r * abs(value)
        std[name] = math.hypot(std[name], bias)
        shared[name] = math.hypot(shared.get(name, 0.0), bias)
    return replace(est, std=std, shared_std=shared)
