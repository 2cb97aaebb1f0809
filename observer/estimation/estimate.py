"""Estimates of a :class:`~observer.recording.Recording`: what ``dcobserver estimate`` runs.

Each requested circuit is estimated over the whole recording with the swarm
settings (and optional search ranges) of an
:class:`~observer.config.EstimateConfig`; the estimators themselves are
:func:`observer.estimation.field.estimate_field` and
:func:`observer.estimation.armature.estimate_armature`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from observer.estimation.armature import estimate_armature
from observer.estimation.field import estimate_field
from observer.estimation.filter_id import (
    IDENTIFIED_WINDINGS,
    FilterFit,
    identify_voltage_filter,
)
from observer.estimation.frontend import applied_mismatch, winding_front_ends
from observer.estimation.ranges import EstimationError, SearchRange
from observer.estimation.result import CircuitEstimate

log = logging.getLogger(__name__)

CIRCUITS = ("field", "armature")

#: Channels each circuit needs.
CIRCUIT_CHANNELS = {"field": ("vf", "if"), "armature": ("va", "ia", "if", "omega")}


def _configured_range(cfg: Any) -> SearchRange | None:
    """A SearchRange from a config section with optional ``R`` and ``L``, or None."""
    if cfg is None or (cfg.R is None and cfg.L is None):
        return None
    if cfg.R is None or cfg.L is None:
        raise EstimationError("a configured search range needs both R and L")
    return SearchRange(tuple(cfg.R), tuple(cfg.L))


def estimate_recording(
    rec: Any,
    circuits: tuple[str, ...] = CIRCUITS,
    settings: Any = None,
    *,
    path: str | None = None,
    chain: Any = None,
) -> dict[str, CircuitEstimate]:
    """Estimate the requested circuits of a :class:`~observer.recording.Recording`.

    Parameters
    ----------
    rec : Recording
    circuits : tuple of {"field", "armature"}
    settings : observer.config.EstimateConfig, optional
        Swarm settings and optional search ranges; defaults apply when omitted.
    path : str, optional
        File name used in error messages.
    chain : observer.config.ChainConfig, optional
        The measurement chain, as far as it is known (intersample model, the
        channels' front ends); unknown parts are decided from the data.
    """
    from observer.config import EstimateConfig

    cfg = settings if settings is not None else EstimateConfig()
    out: dict[str, CircuitEstimate] = {}
    common = dict(
        n_particles=cfg.particles,
        max_iterations=cfg.iterations,
        schedule=cfg.schedule,
        w=cfg.inertia,
        polish=cfg.polish,
    )
    for circuit in circuits:
        if circuit not in CIRCUIT_CHANNELS:
            raise EstimationError(f"unknown circuit {circuit!r}; expected one of {CIRCUITS}")
        rec.require(*CIRCUIT_CHANNELS[circuit], path=path, purpose=f"the {circuit} circuit")
        # One seed per circuit, so estimating one circuit alone gives the same numbers.
        rng = np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)])
        prefix = f"{path}: " if path else ""
        chain_kw: dict[str, Any] = {
            "intersample": chain.intersample if chain is not None else "auto",
            "front_ends": winding_front_ends(chain, circuit),
        }
        fit = None
        if (
            circuit in IDENTIFIED_WINDINGS
            and chain_kw["front_ends"] is None
            and chain_kw["intersample"] in ("auto", "smooth")
        ):
            fit = voltage_filter(rec, circuit, prefix)
            chain_kw["voltage_alias"] = fit.alias
            if fit.alias is not None:
                chain_kw["identified_filter"] = fit.best
        try:
            first = _estimate(circuit, rec, rng, cfg, common, chain_kw)
            est = with_learned_mismatch(
                first,
                lambda circuit=circuit, chain_kw=chain_kw, **kw: _estimate(
                    circuit, rec, np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)]),
                    cfg, common, chain_kw | kw,
                ),
            )  # fmt: skip
        except EstimationError as exc:
            raise EstimationError(f"{prefix}{circuit} circuit: {exc}") from None
        if fit is not None and est.intersample == "smooth":
            est = dataclasses.replace(est, voltage_filter={**fit.to_dict(), "text": fit.text})
        out[circuit] = est
    return out


def voltage_filter(rec: Any, circuit: str, prefix: str = "") -> FilterFit:
    """The untold voltage filter, identified from the converter's jumps in the recording's
    voltage of ``circuit`` (its ``alias`` None: not identified; the weakest filter in use is
    then assumed)."""
    channel = CIRCUIT_CHANNELS[circuit][0]
    fit = identify_voltage_filter(np.asarray(rec[channel], dtype=float), rec.dt)
    if fit.alias is None:
        log.debug("%s%s voltage filter not identified: %s", prefix, circuit, fit.reason)
    else:
        log.debug(
            "%s%s voltage filter identified from %d jumps: %s (residual %.3g V), aliasing "
            "factor %.4f", prefix, circuit, fit.jumps, fit.text, fit.rms_v,
            fit.alias,
        )  # fmt: skip
    return fit


def with_learned_mismatch(
    first: CircuitEstimate, refit: Callable[..., CircuitEstimate]
) -> CircuitEstimate:
    """``first``, or where its untold channels differ like the commonest pair
    (:func:`~observer.estimation.frontend.applied_mismatch` of its ``mismatch_size``), the
    estimate once more by ``refit(mismatch=..., shift=...)``: the voltage corrected for the
    mismatch, from the delay that goes with it."""
    if not applied_mismatch(first.mismatch_size):
        return first
    return refit(mismatch=first.mismatch_size, shift=first.mismatch_shift)


def _estimate(
    circuit: str,
    rec: Any,
    rng: np.random.Generator,
    cfg: Any,
    common: dict[str, Any],
    chain_kw: dict[str, Any],
) -> CircuitEstimate:
    if circuit == "field":
        return estimate_field(
            rec["vf"], rec["if"], rec.dt, rng=rng,
            search_range=_configured_range(cfg.field), **common, **chain_kw,
        )  # fmt: skip
    return estimate_armature(
        rec["va"], rec["ia"], rec["if"], rec["omega"], rec.dt, rng=rng,
        search_range=_configured_range(cfg.armature), **common, **chain_kw,
    )  # fmt: skip
