"""Estimates of a :class:`~observer.recording.Recording`: what ``dcobserver estimate`` runs.

Each requested circuit is estimated over the whole recording with the swarm
settings (and optional search ranges) of an
:class:`~observer.config.EstimateConfig`; the estimators themselves are
:func:`observer.estimation.field.estimate_field` and
:func:`observer.estimation.armature.estimate_armature`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
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
from observer.estimation.frontend import applied_mismatch, gain_tolerances, winding_front_ends
from observer.estimation.linearity import (
    Fold,
    Linearity,
    applies_to,
    field_note,
    made_by_a_bridge,
    nonlinear_note,
    voltage_linearity,
)
from observer.estimation.ranges import EstimationError, SearchRange
from observer.estimation.result import CircuitEstimate, with_gain_tolerance

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
        # The model error that depends on the operating point, which a recording spans.
        split_by_voltage=True,
    )
    for circuit in circuits:
        if circuit not in CIRCUIT_CHANNELS:
            raise EstimationError(f"unknown circuit {circuit!r}; expected one of {CIRCUITS}")
        rec.require(*CIRCUIT_CHANNELS[circuit], path=path, purpose=f"the {circuit} circuit")
        out[circuit] = _estimate_circuit(circuit, rec, cfg, common, chain, path)
    if "armature" in out:
        # The armature voltage reading's linearity over the recording
        # (:mod:`~observer.estimation.linearity`): a reading that follows a curve of the
        # voltage does not describe the motor, whatever the fit says; nor does a field chopper's
        # beside it. Not where the model puts the waveform between the samples itself.
        result = (
            voltage_linearity(rec["va"], rec["ia"], rec.dt, rec["if"], rec["omega"])
            if applies_to(out["armature"].intersample)
            else None
        )
        fold = result.correction if result is not None else None
        va = np.asarray(rec["va"], dtype=float)
        if fold is not None and not made_by_a_bridge(va, rec.dt, winding="armature"):
            # A converter's pulses folded onto zero frequency, periodic in the voltage: taken
            # out of the reading, and the armature estimated again from it (a bridge's jumps
            # are put back between the samples instead, their fold with them).
            corrected = _WithVoltage(rec, "va", va - fold.of_samples(va, rec.dt))
            out["armature"] = _estimate_circuit("armature", corrected, cfg, common, chain, path)
            if "field" in out:
                vf = np.asarray(rec["vf"], dtype=float)
                out["field"] = with_field_fold(out["field"], fold, vf, rec.dt)
        out["armature"] = with_linearity(out["armature"], result)
        if "field" in out:
            out["field"] = not_described(out["field"], field_note(result, rec["vf"], rec.dt))
    return {c: with_gain_tolerance(e, gain_tolerances(chain, c)) for c, e in out.items()}


def _estimate_circuit(
    circuit: str, rec: Any, cfg: Any, common: dict[str, Any], chain: Any, path: str | None
) -> CircuitEstimate:
    """One circuit's estimate of :func:`estimate_recording`: its untold voltage filter
    identified, the estimate, and again where untold channels differ."""
    # One seed per circuit, so estimating one circuit alone gives the same numbers.
    rng = np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)])
    prefix = f"{path}: " if path else ""
    chain_kw: dict[str, Any] = {
        "intersample": chain.intersample if chain is not None else "auto",
        "front_ends": winding_front_ends(chain, circuit),
    }
    fit, identified = untold_filter(rec, circuit, chain_kw, prefix)
    chain_kw |= identified
    try:
        first = _estimate(circuit, rec, rng, cfg, common, chain_kw)
        est = with_learned_mismatch(
            first,
            lambda circuit=circuit, chain_kw=chain_kw, **kw: _estimate(
                circuit, rec, np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)]),
                cfg, common, chain_kw | kw,
            ),
            noisier=functools.partial(_noisier, circuit, rec, cfg, common, chain_kw),
        )  # fmt: skip
    except EstimationError as exc:
        raise EstimationError(f"{prefix}{circuit} circuit: {exc}") from None
    if fit is not None and est.intersample == "smooth":
        est = dataclasses.replace(est, voltage_filter={**fit.to_dict(), "text": fit.text})
    return est


def untold_filter(
    rec: Any, circuit: str, chain_kw: dict[str, Any], prefix: str = ""
) -> tuple[FilterFit | None, dict[str, Any]]:
    """Where ``circuit``'s chain options ``chain_kw`` leave its front ends untold and its
    voltage may be read as measured (``auto`` or ``smooth``): the voltage filter identified
    from the recording (:func:`voltage_filter`), and the estimator's options for it, its
    aliasing factor and (identified) the filter, whose jumps are then put back between the
    samples. Else ``(None, {})``. ``estimate``, ``diagnose`` and the benches all read an untold
    chain this way."""
    if (
        circuit not in IDENTIFIED_WINDINGS
        or chain_kw.get("front_ends") is not None
        or chain_kw.get("intersample", "auto") not in ("auto", "smooth")
    ):
        return None, {}
    fit = voltage_filter(rec, circuit, prefix)
    options: dict[str, Any] = {"voltage_alias": fit.alias}
    if fit.alias is not None:
        options["identified_filter"] = fit.best
    return fit, options


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


#: Seed of the white noise :func:`with_learned_mismatch` adds to a voltage (fixed: the same
#: recording always gives the same estimate).
SIMEX_SEED = 20261127


def simex_noise(n: int, var: float) -> np.ndarray:
    """The white noise of variance ``var`` (V^2) that :func:`with_learned_mismatch` (and the
    daemon's chain decision) adds to ``n`` voltage samples: always the same draws."""
    return np.random.default_rng(SIMEX_SEED).standard_normal(n) * math.sqrt(var)


class _WithVoltage:
    """A recording whose ``channel`` reads ``values`` instead."""

    def __init__(self, rec: Any, channel: str, values: np.ndarray) -> None:
        self._rec = rec
        self._channel = channel
        self._values = values
        self.dt = rec.dt

    def __getitem__(self, name: str) -> Any:
        return self._values if name == self._channel else self._rec[name]


def _with_voltage_noise(rec: Any, channel: str, var: float) -> _WithVoltage:
    """``rec`` whose ``channel`` carries white noise of variance ``var`` (V^2) more."""
    x = np.asarray(rec[channel], dtype=float)
    return _WithVoltage(rec, channel, x + simex_noise(x.shape[0], var))


def with_learned_mismatch(
    first: CircuitEstimate,
    refit: Callable[..., CircuitEstimate],
    noisier: Callable[[float], CircuitEstimate] | None = None,
) -> CircuitEstimate:
    """``first``, or where its untold channels differ like the commonest pair
    (:func:`~observer.estimation.frontend.applied_mismatch` of its ``mismatch_size``), the
    estimate once more by ``refit(mismatch=..., shift=...)``: the voltage corrected for the
    mismatch, from the delay that goes with it.

    The voltage's own noise reads as such a mismatch too: on channels filtered alike, the
    P-12 at 2 % sensor noise (2 kHz) measured 0.77 of the commonest pair (0.72 from the
    voltage's noise alone, 0.40 from the field current's), and corrected for it read La
    +6.0 % instead of −0.2 %. Given ``noisier(var)``, the same estimate with white noise of
    the variance the first one read (``input_noise_var``) added to the voltage, the size is
    extrapolated to no noise (simulation-extrapolation, SIMEX: the size grows with the
    noise's variance, ``size(0) = 2 size(var) - size(2 var)``): 0.77 -> 0.20 there, not
    corrected for; channels that do differ (RC voltages beside Butterworth currents) 1.48 ->
    1.01 at 2 % and 1.03 -> 0.99 at 0.2 %.
    """
    size = first.mismatch_size
    if not applied_mismatch(size):
        return first
    if noisier is not None and first.input_noise_var > 0.0:
        size = 2.0 * size - noisier(first.input_noise_var).mismatch_size
        log.debug(
            "%s: the channels' mismatch %.3f measured, %.3f without the voltage's noise",
            first.circuit, first.mismatch_size, size,
        )  # fmt: skip
        if not applied_mismatch(size):
            return first
    return refit(mismatch=size, shift=first.mismatch_shift)


def with_linearity(est: CircuitEstimate, result: Linearity | None) -> CircuitEstimate:
    """The armature's ``est`` with its voltage reading's linearity test ``result``, not
    describing its window where the reading follows a curve (None: not tested)."""
    if result is None:
        return est
    est = dataclasses.replace(est, voltage_linearity=result.to_dict())
    return not_described(est, nonlinear_note(result, "armature"))


def with_field_fold(
    est: CircuitEstimate, fold: Fold | None, field_voltage: np.ndarray, dt: float
) -> CircuitEstimate:
    """The field's ``est`` beside an armature whose reading showed a converter's folded pulses
    (``fold``), with the fold's size as a possible offset of its voltage in its std.

    A field chopper's pulses fold alike on the drive's PWM clock, but the field's voltage sits
    at a few steady levels, where a fold is an offset that ``Rf`` takes up whole and no curve
    can show: the P-12 behind a chopper at 10 kHz had Rf 0.1-0.3 % off at 5-85 std, its
    steady voltage read as a held reference with nothing for an offset in its std. The
    armature's fold's peak (:attr:`~observer.estimation.linearity.Fold.peak_v`), scaled from
    the armature's largest voltage to the field's (a pulse's harmonics are proportional to
    its height, the converter's supply) and taken as one std of such an offset, moves ``R``
    by ``peak / mean(v)`` (an offset of a steady winding's voltage is ``R``'s whole), shared
    by every window at that level. (Unscaled, the 440 V motor's 1 V fold held 70 % of its
    field's windows, honest before.) Where the window steps from one level to another, the
    two levels' offsets differ, and the current's answer to the step reads that as
    inductance (the same recordings: Lf 1-2 % off at 6-25 std where the field stepped by 55
    V); the same bound on ``L`` over the step's size held most windows and not those, and
    was left out. Unchanged without a fold, or where the field's voltage shows a bridge's
    ripple (a bridge's jumps are put back between the samples, their fold with them)."""
    if fold is None or made_by_a_bridge(field_voltage, dt, winding="field"):
        return est
    v = np.asarray(field_voltage, dtype=float)
    mean_v = float(np.mean(np.abs(v)))
    if not (mean_v > 0 and fold.largest_v > 0):
        return est
    peak = fold.peak_for(v)
    move = est.resistance_ohm * peak / mean_v
    std, shared = dict(est.std), dict(est.shared_std)
    std["R"] = math.hypot(std["R"], move)
    shared["R"] = math.hypot(shared.get("R", 0.0), move)
    return dataclasses.replace(est, std=std, shared_std=shared)


def not_described(est: CircuitEstimate, note: str) -> CircuitEstimate:
    """``est`` not describing its window for the reason ``note`` (unchanged without one)."""
    if not note:
        return est
    return dataclasses.replace(
        est, describes_window=False, note="; ".join(n for n in (est.note, note) if n)
    )


def _noisier(
    circuit: str, rec: Any, cfg: Any, common: dict[str, Any], chain_kw: dict[str, Any], var: float
) -> CircuitEstimate:
    """The circuit's estimate with white noise of variance ``var`` (V^2) more on its voltage."""
    noisy = _with_voltage_noise(rec, CIRCUIT_CHANNELS[circuit][0], var)
    rng = np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)])
    # Only its mismatch_size is used: the std's operating-point refits would be wasted.
    return _estimate(circuit, noisy, rng, cfg, common | {"split_by_voltage": False}, chain_kw)


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
