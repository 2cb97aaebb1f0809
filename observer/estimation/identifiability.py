"""Which parameters an estimate identifies: the rule the daemon's quality flags follow.

A parameter is *identified* by a window when

- the estimator says its model describes the window
  (:attr:`~observer.estimation.result.CircuitEstimate.describes_window`; when it
  does not, nothing in the estimate is evidence, whatever its ``std``);
- its value is finite and its relative one-sigma uncertainty
  (:meth:`~observer.estimation.result.CircuitEstimate.relative_std`) is at most
  the limit for its kind (``R``, ``L``, ``K``; ``[observer.quality]`` in the
  config, defaults in :class:`observer.config.QualityConfig`);
- for the armature, ``R`` and ``K`` are identified together: they share the
  static balance ``va = Ra*ia + K*if*omega``, and one without the other is a
  biased split.

The rule does not know how the uncertainty is computed: it takes the
estimator's ``std`` and ``describes_window`` as they come.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from observer.estimation.result import CircuitEstimate

#: Parameters of each circuit, in display order.
CIRCUIT_PARAMS: dict[str, tuple[str, ...]] = {"field": ("R", "L"), "armature": ("R", "L", "K")}


@dataclass(frozen=True)
class Identification:
    """Per parameter: identified or not, and why not.

    Attributes
    ----------
    identified : dict
        ``{"R": True, "L": False, ...}``.
    reasons : dict
        For each parameter not identified, one short sentence why.
    """

    identified: Mapping[str, bool]
    reasons: Mapping[str, str]

    def quality(self) -> dict[str, str]:
        """``"ok"`` or ``"none"`` per parameter, as the daemon reports a window without history."""
        return {p: ("ok" if ok else "none") for p, ok in self.identified.items()}

    @property
    def unidentified(self) -> tuple[str, ...]:
        return tuple(p for p, ok in self.identified.items() if not ok)


def identify(est: CircuitEstimate, limits: Mapping[str, float]) -> Identification:
    """Apply the identification rule to one circuit's estimate.

    Parameters
    ----------
    est : CircuitEstimate
    limits : mapping
        Largest relative std per parameter kind, ``{"R": 0.01, "L": 0.1, "K": 0.01}``.

    Returns
    -------
    Identification
    """
    params = CIRCUIT_PARAMS[est.circuit]
    identified: dict[str, bool] = {}
    reasons: dict[str, str] = {}
    for p in params:
        value = est.value(p)
        rel = est.relative_std(p) if p in est.std else math.inf
        if not est.describes_window:
            identified[p] = False
            reasons[p] = "the model does not describe the data" + (
                f" ({est.note})" if est.note else ""
            )
        elif value is None or not math.isfinite(value):
            identified[p] = False
            reasons[p] = "no finite value"
        elif not rel <= limits[p]:
            identified[p] = False
            if not math.isfinite(rel):
                rel_text = "infinite"
            else:
                rel_text = f"{100 * rel:.0f} %" if rel >= 1 else f"{100 * rel:.3g} %"
            reasons[p] = f"relative std {rel_text} > {100 * limits[p]:g} %"
            shared = est.relative_shared_std(p)
            if shared > limits[p]:
                # A bias every window shares (a sensor's configured gain tolerance, an
                # offset, the chain): no longer recording brings the parameter within.
                reasons[p] += (
                    f", of which {100 * shared:.3g} % every window shares (sensor gain "
                    "tolerance or offset, the chain): more data will not bring it within"
                )
        else:
            identified[p] = True
    if est.circuit == "armature" and identified["R"] != identified["K"]:
        # R and K share the static balance: one without the other is a biased split.
        for p, other in (("R", "K"), ("K", "R")):
            if identified[p]:
                identified[p] = False
                reasons[p] = f"identified only together with {other}, which is not"
    return Identification(identified, reasons)
