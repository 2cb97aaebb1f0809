"""What a diagnosis finds: the noise floor, located mismatch, findings and the verdict."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from observer.diagnosis.effects import DataContext
from observer.estimation import CircuitEstimate

NONE = "none"
UNEXPLAINED = "unexplained"

CURRENT_CHANNEL = {"field": "if", "armature": "ia"}


@dataclass(frozen=True)
class NoiseFloor:
    """What a correct model's residual would look like, for one circuit.

    Attributes
    ----------
    variance_a2 : float
        Expected residual variance of a correct model (A^2): ``white + coloured``.
    white_a2, coloured_a2 : float
        Current-sensor (white) and input-noise-through-the-model (AR(1)) parts.
    pole : float
        The model's discrete pole ``a = exp(-R dt / L)``.
    tau_int : float
        Integrated autocorrelation time of the floor process (samples): a mean
        over ``m`` samples has variance ``variance_a2 * tau_int / m``.
    residual_a2 : float
        The baseline residual's actual variance (A^2).
    """

    circuit: str
    variance_a2: float
    white_a2: float
    coloured_a2: float
    pole: float
    tau_int: float
    residual_a2: float

    @property
    def excess_ratio(self) -> float:
        """rms(residual) / rms(floor): 1 for a correct model."""
        return math.sqrt(self.residual_a2 / self.variance_a2)


@dataclass(frozen=True)
class Mismatch:
    """A time segment where the residual exceeds the floor."""

    t0: float
    t1: float
    channel: str
    conditions: str
    z: float


@dataclass(frozen=True)
class ConditionStructure:
    """Residual binned against one operating condition."""

    channel: str
    condition: str
    z: float
    centers: tuple[float, ...]
    means: tuple[float, ...]
    sigma: tuple[float, ...]
    description: str
    #: Largest bin offset (or periodic amplitude) relative to the floor's rms: the effect size.
    size: float = 0.0


@dataclass(frozen=True)
class Finding:
    """One candidate's fit and the evidence for it."""

    effect: str
    explanation: str
    equation: str
    params: dict[str, float]
    magnitude: dict[str, float]
    corrected: dict[str, dict[str, float]]
    rms_before: float
    rms_after: float
    channel: str
    accepted: bool
    evidence: dict[str, Any]
    full: np.ndarray = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "explanation": f"{self.explanation}. Adds: {self.equation}",
            "params": {**self.params, **self.magnitude},
            "rms_before": self.rms_before,
            "rms_after": self.rms_after,
            "evidence": {
                **self.evidence,
                "accepted": self.accepted,
                "channel": self.channel,
                "corrected": self.corrected,
            },
        }


@dataclass(frozen=True)
class ChainFinding:
    """Structure in the residual that the measurement chain explains, not the motor.

    Attributes
    ----------
    channel : str
        The voltage channel (``va`` or ``vf``).
    kind : str
        ``jumps_between_samples``: the structure sits in the intervals across a
        converter's jumps, which the samples do not describe.
    description, advice : str
        What was found, and what to do about it.
    """

    channel: str
    kind: str
    description: str
    advice: str


@dataclass(frozen=True)
class Diagnosis:
    """The outcome of :func:`diagnose`."""

    verdict: str
    description: str
    baseline: dict[str, CircuitEstimate]
    baseline_rms: dict[str, float]
    floors: dict[str, NoiseFloor]
    mismatch: tuple[Mismatch, ...]
    structure: tuple[ConditionStructure, ...]
    findings: tuple[Finding, ...]
    context: DataContext
    baseline_full: np.ndarray = field(repr=False)
    baseline_k: float = 0.0
    #: Whole-record residuals (A) of the baseline and of the top finding, per circuit.
    residuals_before: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    residuals_after: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    conditions: dict[str, tuple[np.ndarray, str]] = field(default_factory=dict, repr=False)
    #: The plain model refitted as the extensions are (same segments and compensation).
    plain_refit: dict[str, dict[str, float]] = field(default_factory=dict)
    #: What the measurement chain, not the motor, does to the residual.
    chain: tuple[ChainFinding, ...] = ()
    #: Each winding voltage's intersample model (``model``, ``shift`` in sample periods).
    intersample: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def best(self) -> Finding | None:
        """The finding the verdict names, if any."""
        for f in self.findings:
            if f.effect == self.verdict:
                return f
        return None

    def to_dict(self) -> dict[str, Any]:
        """The ``--json`` contract of ``dcobserver diagnose``."""
        return {
            "verdict": self.verdict,
            "description": self.description,
            "baseline": {
                "field": self.baseline["field"].to_dict(),
                "armature": self.baseline["armature"].to_dict(),
                "rms": dict(self.baseline_rms),
                "refit": self.plain_refit,
            },
            "noise_floor": {
                c: {
                    "rms": math.sqrt(f.variance_a2),
                    "white_rms": math.sqrt(f.white_a2),
                    "coloured_rms": math.sqrt(f.coloured_a2),
                    "tau_int_samples": f.tau_int,
                    "excess_ratio": f.excess_ratio,
                }
                for c, f in self.floors.items()
            },
            "mismatch": [
                {"t0": m.t0, "t1": m.t1, "channel": m.channel, "conditions": m.conditions, "z": m.z}
                for m in self.mismatch
            ],
            "structure": [
                {
                    "channel": s.channel,
                    "condition": s.condition,
                    "z": s.z,
                    "size": s.size,
                    "description": s.description,
                }
                for s in self.structure
            ],
            "findings": [f.to_dict() for f in self.findings],
            "intersample": self.intersample,
            "chain": [
                {
                    "channel": c.channel,
                    "kind": c.kind,
                    "description": c.description,
                    "advice": c.advice,
                }
                for c in self.chain
            ],  # fmt: skip
        }
