"""Model-discrepancy diagnosis: locate where the plain model misses, name the physics, fit it.

:func:`diagnose` runs six stages on a recording with ``va, ia, vf, if, omega``,
each a function of its own:

1. **Baseline** (:func:`fit_baseline`): the plain model (field RL; armature RL
   + ``K*if*omega``) fitted to the whole recording by
   :func:`observer.estimation.field.estimate_field` and
   :func:`~observer.estimation.armature.estimate_armature`, *without* the
   errors-in-variables compensation: that compensation reads an input-noise
   variance from the residual's autocorrelation, and an unmodelled effect's
   slow structure is read as (a lot of) input noise, which drives ``La`` to
   the bottom of its range. The diagnosis wants the residual as it is.
2. **Noise floor** (:func:`noise_floors`): per circuit, a model of what a
   correct model's residual looks like: white current noise plus
   input-voltage noise through the winding's own first-order response (an
   AR(1) with the model's pole), see :mod:`observer.diagnosis.noise_floor`.
3. **Locate** (:func:`locate_mismatch`): what exceeds the floor -- slow
   structure -- is looked for in time windows and in bins of operating
   conditions (field current, ``|ia|``, sign of ``ia``, speed, time /
   accumulated losses, current slope), with bin means judged against the
   floor's variance for that many *correlated* samples
   (:mod:`observer.diagnosis.locate`).
4. **Candidates** (:func:`fit_candidates`): every effect of
   :data:`observer.diagnosis.effects.LIBRARY` extends the model with a few
   physical parameters, fitted by the paper's PSO warm-started from the
   baseline and polished by Levenberg-Marquardt, on half the recording's
   segments (:mod:`observer.diagnosis.fitting`).
5. **Selection** (:func:`select_effects`): each is scored on the other half
   (segment by segment, so the t-statistic carries the residual's
   correlation), by an information criterion with an effective sample size
   (``n / tau_int``), and by how much of the located structure it removes. The
   best single effects are combined in pairs.
6. **Verdict** (:func:`decide_verdict`): the best effect (or pair) that earns
   its parameters on held-out data, refitted on all segments; ``none`` if
   nothing does and no structure was located; ``unexplained`` if structure was
   located but nothing removes it (then the residual is described, e.g.
   periodic at a multiple of shaft speed).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from observer.diagnosis import kernels as dk
from observer.diagnosis.chain import (
    VoltageSpectrum,
    alias_finding,
    aliased_finding,
    averaged_finding,
    current_filter_finding,
    field_folded_finding,
    folded_finding,
    front_end_finding,
    locked_finding,
    no_filter_finding,
    pulses_bound_finding,
    pulses_folded_finding,
    pwm_finding,
    skew_finding,
    voltage_spectrum,
)
from observer.diagnosis.effects import LIBRARY, Combination, DataContext, Effect, context_from
from observer.diagnosis.fitting import (
    CandidateModel,
    Fit,
    FitData,
    baseline_full_vector,
    fit_candidate,
    segment_sse,
    split_segments,
)
from observer.diagnosis.locate import binned_structure, conditions, locate, periodic_structure
from observer.diagnosis.noise_floor import noise_floor, resolution_variance
from observer.diagnosis.results import (
    CURRENT_CHANNEL,
    NONE,
    UNEXPLAINED,
    ChainFinding,
    ConditionStructure,
    Diagnosis,
    Finding,
    Mismatch,
    NoiseFloor,
)
from observer.estimation import CircuitEstimate, estimate_armature, estimate_field
from observer.estimation.armature import aliased_bands, armature_problem
from observer.estimation.estimate import untold_filter, voltage_filter
from observer.estimation.field import DEALIASED as FIELD_DEALIASED
from observer.estimation.filter_id import FilterFit
from observer.estimation.frontend import winding_front_ends
from observer.estimation.intersample import (
    MIN_SWITCHED_SHARE,
    InputModel,
    alias_factor,
    find_switching,
)
from observer.estimation.linearity import (
    Linearity,
    applies_to,
    field_note,
    made_by_a_bridge,
    voltage_linearity,
)
from observer.estimation.lines import notch, settle_samples
from observer.estimation.problem import make_problem
from observer.estimation.ranges import kernel_array
from observer.recording import Recording

log = logging.getLogger(__name__)

#: Held-out log-likelihood ratio (in independent samples) an effect must reach.
MIN_HOLDOUT_LR = 15.0
#: Relative held-out improvement it must reach.
MIN_HOLDOUT_GAIN = 0.002
#: Structure this strong (or a located window, or a periodic component) with no effect
#: that removes it makes the verdict ``unexplained`` rather than ``none``. Weaker binned
#: structure is reported but not enough: the plain fit's own errors-in-variables bias
#: leaves a faint dependence on current transients in clean recordings (z up to ~7).
UNEXPLAINED_Z = 10.0
#: ... and at least this large against the floor's rms: in a long recording a tiny,
#: harmless systematic error becomes significant; it must also matter.
UNEXPLAINED_SIZE = 0.05

#: A residual this many times the noise floor's rms is unexplained (also after a named
#: effect's fit).
UNEXPLAINED_EXCESS = 1.5

#: A relative delay of the voltage channel beyond this (sample periods) is taken for
#: the winding's physics, not the chain's (see :func:`fit_baseline`).
CHAIN_SHIFT = 0.25

Segments = tuple[np.ndarray, np.ndarray]
"""``(starts, stops)`` sample indices of a set of segments."""


# ------------------------------------------------------------------ 1. baseline


@dataclass(frozen=True)
class Baseline:
    """The plain model fitted to the whole recording, and what the later stages build on.

    Attributes
    ----------
    field, armature : CircuitEstimate
        The plain estimates (armature without errors-in-variables compensation).
    full : ndarray
        The same as the diagnosis kernels' full parameter vector.
    context : DataContext
        What the effects' parameter bounds are derived from.
    data : FitData
        The recording's arrays as the kernels take them.
    residuals : dict
        Whole-record residual (A) per circuit, ``"field"`` then ``"armature"``.
    k : float
        ``K`` of the armature residual's projection.
    rms : dict
        RMS of each residual (A).
    shifts : dict
        Per circuit, the relative delay of the voltage behind the current the
        estimator fitted first, and its standard deviation (sample periods),
        kept when the baseline was refitted without it.
    averaged : tuple of str
        Circuits whose untold voltage channel reads as averaged over each sample period (an
        integrating ADC), fitted so (:func:`averaged_reading`); empty: none.
    """

    field: CircuitEstimate
    armature: CircuitEstimate
    full: np.ndarray
    context: DataContext
    data: FitData
    residuals: dict[str, np.ndarray]
    k: float
    rms: dict[str, float]
    shifts: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    averaged: tuple[str, ...] = ()


#: An averaging voltage channel reads half a sample period behind the current: a fitted
#: delay within this of it (sample periods) is tested for one (:func:`averaged_reading`).
AVERAGED_SHIFT_TOL = 0.15

#: The swarm of the armature's first estimate that finds its aliased lines.
ALIAS_SEARCH_PARTICLES, ALIAS_SEARCH_ITERATIONS = 30, 30


def without_aliased_pulses(
    rec: Any, chain: Any = None, *, seed: int = 0
) -> tuple[Any, ChainFinding | None]:
    """``rec`` with the armature's aliased lines notched out of ``va`` and ``ia`` (the notches'
    ringing at the ends cut off), and the ``pulses_aliased`` finding; ``(rec, None)`` where
    there are none. The estimator leaves those bands out
    (:func:`~observer.estimation.armature.aliased_bands`); a diagnosis that kept them would
    read the pulses' alias as a motor effect (a healthy P-12 behind a chopper at 5 kHz came
    back ``unexplained``, ``sampling_skew`` earning +28 % on held-out data)."""
    va, ia, i_f, omega = (kernel_array(rec[c]) for c in ("va", "ia", "if", "omega"))
    kw: dict[str, Any] = {
        "intersample": chain.intersample if chain is not None else "auto",
        "front_ends": winding_front_ends(chain, "armature"),
    }
    est = estimate_armature(
        va, ia, i_f, omega, rec.dt, n_particles=ALIAS_SEARCH_PARTICLES,
        max_iterations=ALIAS_SEARCH_ITERATIONS, rng=seed, compensate_input_noise=False,
        notch_aliased=False, **kw,
    )  # fmt: skip
    kw["intersample"] = est.intersample
    problem = armature_problem(va, ia, i_f, omega, rec.dt, shift=est.shift_samples, **kw)
    bands = aliased_bands(problem, va, ia, est.resistance_ohm, est.inductance_h)
    edge = settle_samples(bands, rec.dt)
    n = rec.n_samples
    if not bands or n - 2 * edge < n // 2:
        return rec, None
    keep = slice(edge, n - edge)
    signals = {c: np.asarray(rec[c])[keep] for c in rec.channels}
    signals["va"] = notch(va, rec.dt, bands)[keep]
    signals["ia"] = notch(ia, rec.dt, bands)[keep]
    notched = Recording(t=np.asarray(rec.t)[keep], signals=signals, metadata=dict(rec.metadata))
    return notched, aliased_finding("va", "ia", bands)


def armature_linearity(rec: Any) -> Linearity | None:
    """The linearity test of ``rec``'s armature voltage reading
    (:func:`~observer.estimation.linearity.voltage_linearity`)."""
    return voltage_linearity(rec["va"], rec["ia"], rec.dt, rec["if"], rec["omega"])


def linearity_of(
    rec: Any, linearity: Callable[[], Linearity | None] | None = None
) -> Callable[[], Linearity | None]:
    """``linearity`` (the armature reading's linearity test where it is already known), or
    :func:`armature_linearity` of ``rec``, run on first call and kept."""
    if linearity is not None:
        return linearity
    return functools.cache(functools.partial(armature_linearity, rec))


def without_folded_pulses(
    rec: Any, linearity: Callable[[], Linearity | None] | None = None
) -> tuple[Any, ChainFinding | None]:
    """``rec`` with a converter's pulses folded onto its armature voltage taken out
    (:attr:`~observer.estimation.linearity.Linearity.correction`), as the estimator takes them
    out, and the ``pulses_folded`` finding; ``(rec, None)`` where there is no such fold (a
    bridge's voltage is never tested: its jumps are put back between the samples). Kept, the
    fold's slope at the drive's reversals, a gain error of 2-3 %, read as a motor effect: a
    healthy P-12 behind a chopper at 10 kHz came back ``unexplained``. ``linearity``: the test
    of ``rec``'s reading, where it is already known (else it is run)."""
    va = kernel_array(rec["va"])
    if made_by_a_bridge(va, rec.dt, winding="armature"):
        return rec, None
    result = linearity_of(rec, linearity)()
    fold = result.correction if result is not None else None
    if fold is None:
        return rec, None
    signals = {c: np.asarray(rec[c]) for c in rec.channels}
    signals["va"] = va - fold.of_samples(va, rec.dt)
    taken = Recording(t=np.asarray(rec.t), signals=signals, metadata=dict(rec.metadata))
    return taken, pulses_folded_finding("va", fold)


def fit_baseline(
    rec: Any,
    *,
    n_particles: int,
    iterations: int,
    seed: int,
    chain: Any = None,
    keep_delay: bool = False,
) -> Baseline:
    """Stage 1: the plain model on the whole recording, without EIV compensation.

    ``chain`` (an :class:`observer.config.ChainConfig`) is the measurement
    chain as far as the user knows it: its intersample model and the
    channels' front ends, as ``dcobserver estimate --config`` takes them.
    ``keep_delay``: the voltages' relative delays the estimator fitted are the chain's
    (a first pass put them down to it, :func:`diagnose`) and stay in the plain model,
    however large.
    """
    rng = np.random.default_rng(seed)
    dt = rec.dt
    chain_kw: dict[str, dict[str, Any]] = {
        c: {
            "intersample": chain.intersample if chain is not None else "auto",
            "front_ends": winding_front_ends(chain, c),
        }
        for c in ("field", "armature")
    }
    # The field's untold voltage filter, identified from its bridge's jumps and its jumps put
    # back between the samples, as the estimator does: left in, a single-phase bridge's
    # jumps, locked to the samples, err the field's voltage by an offset that follows the
    # firing angle, and the traction motor behind RC voltage filters at 5 kHz came back
    # ``unexplained``, its field residual following the field current at z = 46.
    field_filter, field_options = untold_filter(rec, "field", chain_kw["field"])
    chain_kw["field"] |= field_options
    identified = field_options.get("identified_filter")
    field_est = estimate_field(
        rec["vf"], rec["if"], dt, n_particles=n_particles, max_iterations=iterations, rng=rng,
        **chain_kw["field"],
    )  # fmt: skip
    arm_est = estimate_armature(
        rec["va"], rec["ia"], rec["if"], rec["omega"], dt, n_particles=n_particles,
        max_iterations=iterations, rng=rng, compensate_input_noise=False,
        **chain_kw["armature"],
    )  # fmt: skip
    shifts = {
        "field": (field_est.shift_samples, field_est.shift_std),
        "armature": (arm_est.shift_samples, arm_est.shift_std),
    }
    # A relative delay of a large part of a period is not what a chain of equal
    # filters does: it stands in for a lag of the winding's physics (an eddy path,
    # a late current sensor), which the effects must get to explain. A smooth
    # voltage chosen with it was chosen for that lag: the voltage is held. A switched
    # one was sampled without a filter (clean jumps): beside it, a delay of up to a
    # sample is what the current's own anti-aliasing filter does (a 2nd-order one at
    # fs/4: 0.9 samples), and without it the segments between the jumps, too short to
    # pin R, read the field's Rf -24 % at 2 kHz and located a false mismatch; the chain
    # findings report that delay (:func:`_lag_for_physics`).
    averaged = averaged_reading(rec, arm_est, chain_kw["armature"], n_particles, iterations, rng)
    if averaged is not None:
        arm_est = averaged
        if _reads_averaged(field_est, chain_kw["field"]):
            field_est = estimate_field(
                rec["vf"], rec["if"], dt, n_particles=n_particles, max_iterations=iterations,
                rng=rng, intersample="averaged", fit_shift=False,
            )  # fmt: skip
    if not keep_delay and _lag_for_physics(field_est, field_filter):
        field_est = estimate_field(
            rec["vf"], rec["if"], dt, n_particles=n_particles, max_iterations=iterations,
            rng=rng, intersample=_unpinned(field_est.intersample), fit_shift=False,
            front_ends=chain_kw["field"]["front_ends"],
        )  # fmt: skip
    # The armature's delay is judged as on a held voltage: the diagnosis does not correct its
    # untold channels' mismatch at the ripple as the estimator does, and kept, the delay it
    # fitted beside that mismatch (-0.43 periods behind an RC voltage filter at 2 kHz) left
    # structure ``field_saturation`` took up (the P-12, 6 s, seed 3003; held, ``none``).
    if not keep_delay and _lag_for_physics(arm_est, None):
        arm_est = estimate_armature(
            rec["va"], rec["ia"], rec["if"], rec["omega"], dt, n_particles=n_particles,
            max_iterations=iterations, rng=rng, compensate_input_noise=False,
            intersample=_unpinned(arm_est.intersample), fit_shift=False,
            front_ends=chain_kw["armature"]["front_ends"],
        )  # fmt: skip
    base_full = baseline_full_vector(field_est, arm_est)
    ctx = dataclasses.replace(
        context_from(rec, field_est.resistance_ohm, field_est.inductance_h, arm_est.resistance_ohm),
        current_read_after=shifts["armature"][0] > CHAIN_SHIFT,
    )
    data = FitData(rec, base_full, ctx, chain_inputs(rec, field_est, arm_est, chain, identified))
    rf0, ra0, k0 = data.residuals(base_full, *data.whole_record)
    rms = {c: float(np.sqrt(np.nanmean(r**2))) for c, r in (("field", rf0), ("armature", ra0))}
    return Baseline(
        field_est, arm_est, base_full, ctx, data, {"field": rf0, "armature": ra0}, k0, rms,
        shifts, tuple(c for c, e in (("field", field_est), ("armature", arm_est))
                      if e.intersample == "averaged" and averaged is not None),
    )  # fmt: skip


def _reads_averaged(est: CircuitEstimate, kw: dict[str, Any]) -> bool:
    """Whether ``est`` (untold, ``auto``) put its voltage about half a period behind the
    current with a band-limited model: what an averaging voltage channel shows."""
    return (
        kw["intersample"] == "auto"
        and kw["front_ends"] is None
        and est.intersample == "smooth"
        and abs(est.shift_samples - 0.5) < AVERAGED_SHIFT_TOL
    )


def averaged_reading(
    rec: Any,
    arm_est: CircuitEstimate,
    kw: dict[str, Any],
    n_particles: int,
    iterations: int,
    rng: np.random.Generator,
) -> CircuitEstimate | None:
    """The armature refitted as read by an averaging (integrating) voltage channel, where
    that describes it at least as well as the half period's delay the estimator fitted.

    An untold averaging channel reads half a period behind the current, which the
    band-limited model fits as a delay; the baseline takes a delay of that size for the
    winding's physics (a late current sensor, an eddy path) and refits without it, and the
    averaged samples, held a full period off, left 580 mA rms on a healthy P-12 at 5 kHz
    (26 mA with the delay): ``unexplained``. The armature's converter ripple tells the two
    apart, the field's does not: the mean over each period, with no free delay, fitted that
    P-12 better than the delay (24.0 mA against 26.4; the 440 V motor at 2 kHz 84.6 against
    93.2), and a current sensor truly half a period late worse (33.6 against 31.3).
    ``None``: not such a reading (or the chain is configured).
    """
    if not _reads_averaged(arm_est, kw):
        return None
    averaged = estimate_armature(
        rec["va"], rec["ia"], rec["if"], rec["omega"], rec.dt, n_particles=n_particles,
        max_iterations=iterations, rng=rng, compensate_input_noise=False,
        intersample="averaged", fit_shift=False,
    )  # fmt: skip
    return averaged if averaged.rms_a <= arm_est.rms_a else None


#: A current read behind its filtered converter voltage by less than this (sample periods)
#: is taken for the chain's (:func:`_lag_for_physics`): two anti-aliasing filters between
#: fs/8 and fs/4 differ by about a period at most.
CHAIN_LEAD = 1.0


def _lag_for_physics(est: CircuitEstimate, fit: FilterFit | None) -> bool:
    """Whether ``est``'s fitted relative delay stands in for the winding's physics, and the
    baseline is refitted without it (see :func:`fit_baseline`).

    A voltage read late may: an eddy path quickens the current's first answer and a late
    current sensor reads it early (+0.18 and +0.5 periods on the P-12 at 5 kHz). A current
    read behind its voltage is a slower current channel where the voltage is a converter's
    seen through a filter its jumps identify (``fit``, the field's; an RC voltage filter beside
    Butterworth currents: -0.3 periods), which no effect of the library makes: refitted
    without it, the traction motor at 5 kHz came back ``unexplained`` (the field's residual
    following its current at z = 47). On a held voltage (no filter to identify) a delay of
    either sign, at the end of its range, stands in for an effect (a sensor's offset, the
    field's saturation: -1.5 periods on the armature).
    """
    shift = est.shift_samples
    if est.intersample == "switched" or abs(shift) <= CHAIN_SHIFT:
        return False
    filtered_apart = fit is not None and fit.alias is not None and -CHAIN_LEAD < shift < 0.0
    return not filtered_apart


def _unpinned(model: str) -> str:
    """The intersample model to refit with when ``model`` came with a physical lag."""
    return "hold" if model == "smooth" else model


def chain_inputs(
    rec: Any,
    field_est: CircuitEstimate,
    arm_est: CircuitEstimate,
    chain: Any = None,
    identified_filter: str | None = None,
) -> dict[str, InputModel]:
    """Each winding voltage's intersample model, as the baseline's estimator chose and fitted it.

    The model (``hold``, ``smooth``, ``switched``, ``averaged``) and the
    relative delay of the voltage channel the estimator found are kept fixed:
    every extension is fitted on the same reconstruction of the voltage
    between samples as the plain model, so an effect is not credited with
    what the measurement chain does. A filtered field voltage has its jumps put
    back between the samples (:mod:`observer.estimation.dealias`) through its
    configured filter or, untold, ``identified_filter``, as the estimator does.
    """
    i_f, omega = kernel_array(rec["if"]), kernel_array(rec["omega"])
    field = make_problem(
        kernel_array(rec["vf"]), i_f, rec.dt, field_est.intersample, fit_shift=False,
        shift=field_est.shift_samples, front_ends=winding_front_ends(chain, "field"),
        reconstruct_jumps=FIELD_DEALIASED, identified_filter=identified_filter,
    )  # fmt: skip
    armature = armature_problem(
        rec["va"], rec["ia"], i_f, omega, rec.dt, intersample=arm_est.intersample,
        fit_shift=False, shift=arm_est.shift_samples,
        front_ends=winding_front_ends(chain, "armature"),
    )  # fmt: skip
    return {"field": field.inp, "armature": armature.inp}


# ------------------------------------------------------------------ 2. noise floor


def noise_floors(baseline: Baseline) -> dict[str, NoiseFloor]:
    """Stage 2: the residual a correct model would leave, per circuit."""
    data = baseline.data
    floors = {}
    for circuit, est, v, i in (
        ("field", baseline.field, data.vf, data.i_f),
        ("armature", baseline.armature, data.va, data.ia),
    ):
        a = math.exp(-est.resistance_ohm * data.dt / est.inductance_h)
        b = (1 - a) / est.resistance_ohm
        floors[circuit] = noise_floor(
            circuit, baseline.residuals[circuit], a, b, v, resolution_variance(i)
        )
    return floors


# ------------------------------------------------------------------ 3. locate


@dataclass(frozen=True)
class Located:
    """Where the baseline's residual exceeds the floor."""

    conditions: dict[str, tuple[np.ndarray, str]]
    mismatch: tuple[Mismatch, ...]
    structure: tuple[ConditionStructure, ...]


def locate_mismatch(rec: Any, baseline: Baseline, floors: dict[str, NoiseFloor]) -> Located:
    """Stage 3: time windows and operating conditions where the residual exceeds the floor."""
    arm = baseline.armature
    conds = conditions(rec, arm.inductance_h / arm.resistance_ohm)
    mismatch, structure = locate(rec, baseline.residuals, floors, conds)
    return Located(conds, mismatch, structure)


# ------------------------------------------------------------------ 4. candidates


@dataclass(frozen=True)
class Candidates:
    """Every candidate fitted on the fit segments; ``NONE`` is the plain model refitted alike.

    ``fits`` and ``models`` grow as the selection fits pairs, and the verdict's
    fit is replaced by its refit on all segments.
    """

    weights: dict[str, float]
    fit_segments: Segments
    holdout_segments: Segments
    fits: dict[str, Fit]
    models: dict[str, CandidateModel]


def fit_candidates(
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    names: Sequence[str],
    segments: tuple[np.ndarray, ...],
    *,
    n_particles: int,
    iterations: int,
    seed: int,
    compensate_input_noise: bool,
    bar: Any,
) -> Candidates:
    """Stage 4: the plain model and each named effect, fitted on the fit segments.

    ``segments`` is :func:`~observer.diagnosis.fitting.split_segments`'
    ``(fit starts, fit stops, held-out starts, held-out stops)``.
    """
    data = baseline.data
    weights = {c: 1.0 / floors[c].variance_a2 for c in floors}
    if compensate_input_noise:
        fa = floors["armature"]
        b_a = (1 - fa.pole) / baseline.armature.resistance_ohm
        data.va_noise_var = fa.coloured_a2 * (1 - fa.pole**2) / b_a**2
    fs, fe, hs, he = segments
    candidates: list[Effect | None] = [None] + [LIBRARY[n] for n in names]
    fits: dict[str, Fit] = {}
    models: dict[str, CandidateModel] = {}
    for eff in candidates:
        key = NONE if eff is None else eff.name
        bar.set_description(f"fitting {key}")
        # Extensions start from the plain model refitted like them (and keep its
        # values for the circuit they do not touch).
        model = CandidateModel(
            eff, baseline.context, baseline.full if eff is None else fits[NONE].full
        )
        fits[key] = fit_candidate(
            model, data, fs, fe, weights, n_particles=n_particles, iterations=iterations,
            rng=np.random.default_rng([seed, len(fits)]),
        )  # fmt: skip
        models[key] = model
        bar.update(1)
    return Candidates(weights, (fs, fe), (hs, he), fits, models)


# ------------------------------------------------------------------ 5. selection


def accepted(evidence: dict[str, Any]) -> bool:
    """Whether held-out evidence earns an effect its parameters."""
    return bool(
        evidence["holdout_lr"] >= MIN_HOLDOUT_LR and evidence["holdout_gain"] >= MIN_HOLDOUT_GAIN
    )


class HoldoutScorer:
    """Held-out evidence for one fitted candidate against another (or the plain model)."""

    def __init__(self, data: FitData, cands: Candidates, floors: dict[str, NoiseFloor]) -> None:
        self.data = data
        self.cands = cands
        self.floors = floors
        fs, fe = cands.fit_segments
        n_fit = int(np.sum(fe - fs))
        self.n_eff = {c: n_fit / max(floors[c].tau_int, 1.0) for c in floors}
        self.held = {NONE: self.holdout(NONE)}

    def holdout(self, key: str) -> dict[str, np.ndarray]:
        """Per held-out segment, each circuit's sum of squared residuals (A^2)."""
        f = self.cands.fits[key]
        hs, he = self.cands.holdout_segments
        rf, ra, _ = self.data.residuals(f.full, hs, he, f.k)
        return {"field": segment_sse(rf, hs, he), "armature": segment_sse(ra, hs, he)}

    def evidence(self, key: str, ref: str) -> dict[str, Any]:
        """How much better ``key`` does than ``ref`` on held-out data (and by an IC)."""
        data, floors, n_eff, held = self.data, self.floors, self.n_eff, self.held
        fits, models, weights = self.cands.fits, self.cands.models, self.cands.weights
        fs, fe = self.cands.fit_segments
        hs, he = self.cands.holdout_segments
        model = models[key]
        circuits = model.circuits
        held[key] = self.holdout(key)
        d = sum(weights[c] * (held[ref][c] - held[key][c]) for c in circuits)
        base_sum = float(np.sum(sum(weights[c] * held[ref][c] for c in circuits)))
        s = d.size
        sd = float(np.std(d, ddof=1)) if s > 1 else math.inf
        t_stat = float(np.mean(d) / (sd / math.sqrt(s))) if sd > 0 else 0.0
        # Information criterion (BIC) on the fit segments with the effective sample
        # size. Reported, not a gate: the fits minimise the input-noise-compensated
        # cost, so their raw sums of squares are not exact likelihood optima.
        rf_r, ra_r, _ = data.residuals(fits[ref].full, fs, fe)
        rf_e, ra_e, _ = data.residuals(fits[key].full, fs, fe)
        ic = 0.0
        extra = model.n_params - (models[ref].n_params if ref != NONE else 0)
        for c, rr, re in (("field", rf_r, rf_e), ("armature", ra_r, ra_e)):
            if c in circuits:
                # (floored both ways: a noise-free recording's field can fit exactly)
                ratio = float(max(np.nansum(rr**2), 1e-300) / max(np.nansum(re**2), 1e-300))
                ic += n_eff[c] * math.log(ratio)
        ic -= extra * math.log(sum(n_eff[c] for c in circuits))
        # Held-out log-likelihood ratio, counting independent samples only.
        lr = 0.0
        for c in circuits:
            n_h = float(np.sum(he - hs)) / max(floors[c].tau_int, 1.0)
            lr += n_h * math.log(
                max(float(np.sum(held[ref][c])), 1e-300) / max(float(np.sum(held[key][c])), 1e-300)
            )
        return {
            "holdout_gain": float(np.sum(d) / base_sum) if base_sum > 0 else 0.0,
            "holdout_lr": lr,
            "holdout_t": t_stat,
            "holdout_segments": int(s),
            "ic_gain": ic,
            "n_eff": {c: n_eff[c] for c in circuits},
            "extra_params": extra,
        }


@dataclass(frozen=True)
class Selection:
    """Stage 5's outcome: evidence for every candidate and pair, and the best that earns it.

    ``verdict`` is the best accepted single effect or pair, ``NONE`` if none is
    accepted (the verdict stage may still call it ``unexplained``).
    """

    evidence: dict[str, dict[str, Any]]
    accepted_singles: list[str]
    pairs: list[str]
    verdict: str


def select_effects(
    cands: Candidates,
    scorer: HoldoutScorer,
    names: Sequence[str],
    ctx: DataContext,
    *,
    combine: int,
    n_particles: int,
    iterations: int,
    seed: int,
    bar: Any,
) -> Selection:
    """Stage 5: score each effect on held-out data, then pairs of the best ``combine``."""
    evid = {n: scorer.evidence(n, NONE) for n in names}
    singles = sorted(names, key=lambda n: -evid[n]["holdout_gain"])
    good = [n for n in singles if accepted(evid[n])][:combine]
    pairs: list[str] = []
    for i in range(len(good)):
        for j in range(i + 1, len(good)):
            name = _fit_pair(
                cands, scorer.data, good[i], good[j], ctx, n_particles=n_particles,
                iterations=iterations, seed=seed, bar=bar,
            )  # fmt: skip
            # A pair must beat the better of its two members, and the best single
            # effect, on held-out data.
            member = (
                good[i]
                if evid[good[i]]["holdout_gain"] >= evid[good[j]]["holdout_gain"]
                else good[j]
            )
            ev = scorer.evidence(name, member)
            if member != good[0]:
                ev_best = scorer.evidence(name, good[0])
                if not accepted(ev_best):
                    ev = ev_best
                    member = good[0]
            ev_none = scorer.evidence(name, NONE)
            ev["vs"] = member
            ev["holdout_gain_vs_plain"] = ev_none["holdout_gain"]
            evid[name] = ev
            pairs.append(name)
            bar.update(1)
    return Selection(evid, good, pairs, _best_of(evid, good, pairs, cands))


def _best_of(
    evid: dict[str, dict[str, Any]], good: Sequence[str], pairs: Sequence[str], cands: Candidates
) -> str:
    """The verdict among the accepted singles ``good`` (best first) and the ``pairs`` fitted
    of them: the pair with the most held-out gain over the plain model that is accepted and
    not degenerate, else the best single, else ``none``."""
    if not good:
        return NONE
    best_pairs = [
        p for p in pairs if accepted(evid[p]) and not _degenerate(cands.models[p], cands.fits[p])
    ]
    if best_pairs:
        return max(best_pairs, key=lambda p: evid[p]["holdout_gain_vs_plain"])
    return good[0]


def _fit_pair(
    cands: Candidates,
    data: FitData,
    first: str,
    second: str,
    ctx: DataContext,
    *,
    n_particles: int,
    iterations: int,
    seed: int,
    bar: Any,
) -> str:
    """Fit two effects together, started from their single fits; the pair's name."""
    fits = cands.fits
    combo = Combination(LIBRARY[first], LIBRARY[second])
    bar.set_description(f"fitting {combo.name}")
    start = fits[first].full.copy()
    for q in LIBRARY[second].parameters(ctx):
        k_ = dk.FULL_PARAMS.index(q.name)
        start[k_] = fits[second].full[k_]
    model = CandidateModel(combo, ctx, start, warm_effect=True)
    cands.models[combo.name] = model
    fs, fe = cands.fit_segments
    fits[combo.name] = fit_candidate(
        model, data, fs, fe, cands.weights,
        n_particles=n_particles, iterations=iterations,
        rng=np.random.default_rng([seed, len(fits)]),
    )  # fmt: skip
    return combo.name


# ------------------------------------------------------------------ 6. verdict


@dataclass(frozen=True)
class Verdict:
    """Stage 6's outcome: the verdict, its description, findings ranked and all structure."""

    verdict: str
    description: str
    findings: tuple[Finding, ...]
    structure: tuple[ConditionStructure, ...]
    chain: tuple[ChainFinding, ...] = ()
    #: Why an effect was set aside only as the chain's own reading
    #: (:data:`READ_BY_THE_CHAIN`), for :func:`diagnose` to diagnose again with it kept in
    #: the plain model; "" if none was.
    chain_read: str = ""


def decide_verdict(
    rec: Any,
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    located: Located,
    cands: Candidates,
    selection: Selection,
    names: Sequence[str],
    *,
    n_particles: int,
    iterations: int,
    seed: int,
    linearity: Callable[[], Linearity | None] | None = None,
) -> Verdict:
    """Stage 6: refit the selected effect on all segments, rank the findings, name the verdict.

    ``linearity``: the armature reading's linearity test where it is already known (it is
    run on ``rec`` otherwise, once)."""
    linearity = linearity_of(rec, linearity)
    spectra = voltage_spectra(rec, linearity)
    chain = front_end_findings(rec, baseline, spectra, linearity)
    verdict = selection.verdict
    confounded_here = _confounded_with_chain(chain, baseline.context.current_read_after)
    confounded = confounded_here & set(verdict.split("+"))
    set_aside = ""
    if confounded:
        # Not told apart from the channels' front ends: the best choice without any such.
        set_aside, verdict = verdict, _best_without(selection, cands, confounded_here)
    # The data between the voltage's jumps, built once for whichever of the two tests asks.
    switched = functools.cache(functools.partial(switched_data, rec, baseline))
    jumps: tuple[ChainFinding, ...] = ()
    across = ""
    if verdict != NONE:
        verdict, jumps, across = _without_contradicted(
            switched, floors, cands, selection, verdict, confounded
        )
        chain = (*jumps, *chain)
    if verdict != NONE:
        _refit_on_all_segments(
            cands, baseline.data, verdict, n_particles=n_particles, iterations=iterations,
            seed=seed,
        )  # fmt: skip
    evid = selection.evidence
    keys = list(names) + selection.pairs
    ranked = sorted(
        keys,
        key=lambda n: (
            n != verdict,
            not accepted(evid[n]),
            -evid[n].get("holdout_gain_vs_plain", evid[n]["holdout_gain"]),
        ),
    )
    findings = tuple(_finding(k, baseline, floors, located, cands, evid) for k in ranked)
    description = _describe(verdict, findings, located.structure, located.mismatch, floors)
    if set_aside:
        description += "; " + _set_aside_note(set_aside, confounded)
    if across:
        description += "; " + across
    periodic = _periodic(rec, baseline.residuals, floors)
    structure = tuple(sorted(located.structure + tuple(periodic), key=lambda s_: -s_.z))

    unfiltered = _circuits_with(chain, "no_anti_aliasing")
    # A winding whose voltage reads a curve of the voltage: nothing on it is the motor's.
    curved = _circuits_with(chain, "voltage_folded")
    # A winding fed by pulses that fold onto its reading by up to the bound in its spectrum.
    pulsed = {c for c, s_ in spectra.items() if s_.line and s_.alias_v > 0}
    periodic = [
        s_
        for s_ in periodic
        if _circuit(s_) not in curved
        and not (
            _circuit(s_) in pulsed
            and _offset_v(s_, baseline, floors) <= spectra[_circuit(s_)].alias_v
        )
    ]
    words = [s_.description for s_ in periodic]
    strong = _strong(structure)
    mismatch = located.mismatch
    change_v: dict[str, float] = {}
    if verdict != NONE:
        change_v = effect_size_v(baseline, cands.models[verdict], cands.fits[verdict].full)
        if curved & set(change_v):
            c = sorted(curved & set(change_v))[0]
            description = (
                f"{_describe(NONE, findings, (), (), floors)}; {verdict} would earn its "
                f"parameters, but the {c} circuit's voltage samples follow a curve of the "
                "voltage (see the chain findings): not told apart from the chain"
            )
            verdict = NONE
            change_v = {}
        hidden = {c for c in unfiltered & set(change_v) if change_v[c] < spectra[c].alias_v}
        if hidden:
            # Without a filter, what the converter does above Nyquist folds into the samples
            # unbounded: a motor effect smaller than that cannot be told from the chain.
            c = sorted(hidden)[0]
            description = (
                f"{_describe(NONE, findings, (), (), floors)}; {verdict} would earn its "
                f"parameters, but it changes the {c} circuit's voltage by {change_v[c]:.3g} V "
                f"rms, less than the {spectra[c].alias_v:.3g} V that the {VOLTAGE_CHANNEL[c]} "
                "channel's folded converter content can (no anti-aliasing filter): not told "
                "apart from the chain"
            )
            verdict = NONE
        # It acts only on windings fed by pulses, by less than they fold onto their readings:
        # a field chopper's offset per steady level (the 440 V motor at 10 kHz: an if sensor
        # offset "earned" 0.03 V against a bound of 0.6 V, and 0.009 V on the armature, whose
        # fold, taken out, leaves 0.07 V of slow error).
        bounds = _pulse_bounds(pulsed, spectra, linearity)
        if (
            verdict != NONE
            and change_v
            and all(c in bounds and v < bounds[c] for c, v in change_v.items())
        ):
            c = max(change_v, key=lambda k: change_v[k])
            description = (
                f"{_describe(NONE, findings, (), (), floors)}; {verdict} would earn its "
                f"parameters, but it changes the {c} circuit's voltage by {change_v[c]:.3g} V "
                f"rms, less than the {bounds[c]:.3g} V that a converter's pulses fold "
                f"onto the {VOLTAGE_CHANNEL[c]} channel: not told apart from the chain"
            )
            chain = (pulses_bound_finding(VOLTAGE_CHANNEL[c], spectra[c]), *chain)
            verdict = NONE
    if verdict != NONE:
        left = unexplained_remainder(
            rec, baseline, floors, located, cands.fits[verdict].full, strong
        )
        folded = (
            alias_explains(baseline, floors, left, spectra)
            if left
            and not words
            and all(s_.size < FOLDED_SIZE for s_ in left)
            and all(v < spectra[c].alias_v for c, v in change_v.items())
            else ()
        )
        if folded:
            # The effect changes no winding's voltage by more than its channel's folded
            # converter content can, and what it leaves is no larger either, nor as large
            # as the noise floor: both are the sampling of the converter's voltage (a 6-pulse
            # bridge at 10 kHz behind a filter at fs/4 drifts the samples' mean by ~0.1 V as
            # the firing angle moves).
            named = verdict
            verdict = NONE
            description = (
                f"{_describe(NONE, findings, (), (), floors)}; {named} would earn its "
                "parameters but removes only part of the structure located, and neither is "
                "larger than the voltage channels' folded converter content: "
                + "; ".join(f"{c.description} ({c.advice})" for c in folded)
            )
            return Verdict(verdict, description, findings, structure, folded + chain)
        gain = evid.get(verdict, {}).get("holdout_gain", 1.0)
        if not left and pulsed and words and gain < SLIGHT_GAIN:
            # Behind a chopper the pulses' own structure sets the bar the remainder is measured
            # against; an effect that earns next to nothing beside a component periodic in
            # shaft angle has not explained it (the P-12 at 5 kHz: a back-EMF ripple at 8x
            # shaft speed named sampling_skew, +4.2 % on held-out data).
            left = [s_ for s_ in periodic if s_.z >= UNEXPLAINED_Z]
        if left:
            named = verdict
            verdict = UNEXPLAINED
            located_words = [s_.description for s_ in (periodic if words else strong)[:2]]
            description = (
                "a mismatch is located and the nearest effect in the library "
                f"({named}) removes only part of it; what is left: "
                + "; ".join(s_.description for s_ in left[:2])
                + ("; located before: " + "; ".join(located_words) if located_words else "")
            )
            return Verdict(verdict, description, findings, structure, chain)
    excess = {c for c, f in floors.items() if f.excess_ratio > UNEXPLAINED_EXCESS}
    if verdict == NONE and not words and (strong or mismatch):
        found = chain_explains(rec, baseline, floors, located, strong, switched)
        if not found and not mismatch:
            found = alias_explains(baseline, floors, strong, spectra)
        if found:
            strong, mismatch = [], ()
            description += "; " + "; ".join(f"{c.description} ({c.advice})" for c in found)
            chain = found + chain
    if verdict == NONE and not words and (unfiltered or curved or pulsed):
        # A voltage sampled without an anti-aliasing filter, or fed by pulses that fold onto
        # it, leaves the winding's residual above the floor, in windows and in structure no
        # larger than its folded content can cause: that is the chain's, and said so. Larger
        # structure is not excused.
        beyond = {
            _circuit(s_)
            for s_ in strong
            if _offset_v(s_, baseline, floors) > spectra[_circuit(s_)].alias_v
        }
        excused = ((unfiltered | pulsed) - beyond) | curved
        if excused & (excess | {_circuit(m) for m in mismatch} | {_circuit(s_) for s_ in strong}):
            mismatch = tuple(m for m in mismatch if _circuit(m) not in excused)
            strong = [s_ for s_ in strong if _circuit(s_) not in excused]
            excess -= excused
            description += (
                "; the residual of the "
                + " and ".join(sorted(excused))
                + " circuit is above the noise floor by no more than "
                + (
                    "a voltage sampled without an anti-aliasing filter can leave it"
                    if excused & unfiltered - curved
                    else "a converter's pulses folded onto its voltage can leave it"
                    if excused - curved
                    else "a voltage read through a curve leaves it"
                )
                + " (see the chain findings)"
            )
            chain = tuple(
                pulses_bound_finding(VOLTAGE_CHANNEL[c], spectra[c])
                for c in sorted(
                    excused & pulsed - unfiltered - curved - _circuits_with(chain, "pulses_folded")
                )
            ) + tuple(chain)
    if verdict == NONE and (strong or mismatch or words or excess):
        verdict = UNEXPLAINED
        if not words:
            words = [s.description for s in (strong or structure)[:2]] or [
                f"residual {max(f.excess_ratio for f in floors.values()):.1f}x the noise floor"
            ]
        description = "a mismatch is located but no candidate removes it: " + "; ".join(words)
    if verdict == NONE and curved >= set(VOLTAGE_CHANNEL):
        # Neither winding's voltage is read as the voltage: "adequate" would claim what the
        # recording cannot show (a back-EMF ripple and a brush drop alike read none here).
        description = (
            "no motor effect can be judged from this recording: both windings' voltage "
            "samples follow a curve of the voltage (see the chain findings), so neither the "
            "plain model nor an effect can be tested on them; " + description
        )
    if set_aside and verdict == NONE and confounded - READ_BY_THE_CHAIN:
        # Something earned its parameters and cannot be put down to the motor or the chain.
        verdict = UNEXPLAINED
        description = _set_aside_note(set_aside, confounded)
    elif set_aside and verdict == NONE:
        # Currents read after their voltages: the chain's skew, reported there.
        description = _set_aside_note(set_aside, confounded)
    elif set_aside and verdict == UNEXPLAINED:
        description += "; " + _set_aside_note(set_aside, confounded)
    # What was set aside only as the chain's own reading: diagnosed again with it kept.
    parts = set(set_aside.split("+")) if set_aside else set()
    read = bool(parts & READ_BY_THE_CHAIN) and not (parts & confounded) - READ_BY_THE_CHAIN
    chain_read = _set_aside_note(set_aside, confounded) if read else ""
    return Verdict(verdict, description, findings, structure, chain, chain_read)


#: Effects whose signature a difference between a winding's voltage and current channels'
#: filters leaves too (beyond the delay the estimator fits): a second, faster time constant in
#: the winding's response. Where that winding's channels read skewed (``channel_skew``) the two
#: are not told apart. Measured behind the thyristor drive (the P-12, 6 s, 2 and 10 kHz): eddy
#: currents of coupling 0.15-0.3 read as ``channel_skew`` in 6 of 8 recordings, and a healthy
#: motor whose voltages pass a 4th-order filter at fs/3 beside 2nd-order currents at fs/4, or
#: whose currents and speed one multiplexed ADC samples after the voltages, was named
#: ``eddy_currents`` at 10 kHz.
CONFOUNDED_WITH_SKEW = ("eddy_currents",)


#: A named effect that earns less than this share on held-out data, behind a chopper, beside a
#: component periodic in shaft angle, has not explained it.
SLIGHT_GAIN = 0.1


def _pulse_bounds(
    pulsed: set[str],
    spectra: dict[str, VoltageSpectrum],
    linearity: Callable[[], Linearity | None],
) -> dict[str, float]:
    """What a converter's pulses can fold onto each ``pulsed`` winding's reading that an effect
    could be confused with: the field's offsets per level, bounded by the armature's fold
    scaled to it (``alias_v``); on the armature, whose fold is measured, only what the fold
    leaves unexplained (:attr:`~observer.estimation.linearity.Fold.residual_v`): its own
    shape, periodic in the voltage, is no current-sensor offset (the P-12 at 5 kHz: an
    offset of 0.03 A changed va by 0.077 V, under the fold's peak of 0.099 V but not its
    residual's 0.057 V)."""
    bounds = {c: spectra[c].alias_v for c in pulsed}
    if "armature" in bounds:
        result = linearity()
        if result is not None and result.fold is not None:
            bounds["armature"] = min(bounds["armature"], result.fold.residual_v)
    return bounds


def _first_of_each(chain: Sequence[ChainFinding]) -> tuple[ChainFinding, ...]:
    """``chain`` with one finding per channel and kind, the first (a fold taken out of a
    reading before a bound on it)."""
    seen: set[tuple[str, str]] = set()
    out = []
    for f in chain:
        if (f.channel, f.kind) not in seen:
            seen.add((f.channel, f.kind))
            out.append(f)
    return tuple(out)


def _circuits_with(chain: Sequence[ChainFinding], kind: str) -> set[str]:
    """The circuits whose voltage channel has a chain finding of ``kind``."""
    return {
        c
        for c, v in VOLTAGE_CHANNEL.items()
        if any(f.kind == kind and f.channel == v for f in chain)
    }


def _confounded_with_chain(chain: Sequence[ChainFinding], read_after: bool) -> set[str]:
    """The library's effects the chain findings leave no room to name
    (:data:`CONFOUNDED_WITH_SKEW` on a winding whose channels read skewed; and, ``read_after``,
    currents read after their voltages, ``sampling_skew`` fitted at a negative delay, where
    that is what the skew is: a current offset behind a chopper at 5 kHz was named
    ``sensor_offset+sampling_skew``)."""
    skewed = _circuits_with(chain, "channel_skew")
    out = {n for n in CONFOUNDED_WITH_SKEW if set(LIBRARY[n].circuits) & skewed}
    if read_after and skewed:
        out.add("sampling_skew")
    return out


#: Effects that, set aside where the chain's channels read skewed, are the chain's own reading
#: rather than the motor's (a negative ``sampling_skew``: currents read after their voltages).
#: Set aside, they do not make a verdict ``unexplained``, and the recording is diagnosed again
#: with the voltages' delays the estimator fitted kept in the plain model (:func:`diagnose`):
#: refitted without them, the skew swamped what a motor effect adds (the P-12 at 5 kHz, its
#: currents read half a period late: 0.58 A rms of skew, and a 1 % current sensor offset
#: was ``none``; with them kept, 0.035 A, and the offset is named).
READ_BY_THE_CHAIN = frozenset({"sampling_skew"})


def _best_without(selection: Selection, cands: Candidates, names: set[str]) -> str:
    """The verdict :func:`select_effects` would give without the effects ``names``."""
    return _best_of(
        selection.evidence,
        [n for n in selection.accepted_singles if n not in names],
        [p for p in selection.pairs if not set(p.split("+")) & names],
        cands,
    )


def _set_aside_note(named: str, confounded: set[str]) -> str:
    which = " and ".join(sorted(confounded))
    why = []
    if confounded - READ_BY_THE_CHAIN:
        why.append(
            "a difference between their filters leaves the same second, faster time constant "
            "in its response"
        )
    if "sampling_skew" in confounded:
        why.append(
            "currents read after their voltages (a negative sampling_skew) are that skew: a "
            "multiplexed ADC's order, or a voltage filtered more than its current"
        )
    return (
        f"{named} would earn its parameters, but {which} cannot be told from the chain: the "
        "winding's voltage and current channels read skewed (see the chain findings), and "
        + "; ".join(why)
        + "; configure the channels' front ends ([chain]: filter, delay_us) to tell them apart"
    )


#: Each circuit's voltage channel.
VOLTAGE_CHANNEL = {"field": "vf", "armature": "va"}
#: A named effect must take a located structure's z-score below this share of the
#: strongest one's (and below :data:`UNEXPLAINED_Z`), or what it leaves is unexplained.
REMAINDER_SHARE = 0.25
#: ... and must take every located structure's size (largest offset / floor rms) below this.
REMAINDER_SIZE = 0.5
#: What a named effect leaves is put down to the converter's folded content only if every
#: structure of it is within that content's bound and smaller than the noise floor's rms
#: (a speed sensor's error the library lacks left 1.6-2.7 of it; the folded content of a
#: 6-pulse bridge at 10 kHz behind a filter at fs/4, 0.4-0.7).
FOLDED_SIZE = 1.0


def _periodic(
    rec: Any, residuals: dict[str, np.ndarray], floors: dict[str, NoiseFloor]
) -> list[ConditionStructure]:
    """Components of each circuit's residual periodic in shaft angle (armature first)."""
    return [
        s_
        for c in ("armature", "field")
        if (s_ := periodic_structure(rec, residuals[c], floors[c], CURRENT_CHANNEL[c])) is not None
    ]


def _circuit(item: ConditionStructure | Mismatch) -> str:
    """The circuit whose current channel a located structure or window is on."""
    return "field" if item.channel == CURRENT_CHANNEL["field"] else "armature"


def _offset_v(s_: ConditionStructure, baseline: Baseline, floors: dict[str, NoiseFloor]) -> float:
    """A structure's largest offset as a voltage at the winding (its resistance times it)."""
    circuit = _circuit(s_)
    est = baseline.field if circuit == "field" else baseline.armature
    return s_.size * math.sqrt(floors[circuit].variance_a2) * est.resistance_ohm


def unexplained_remainder(
    rec: Any,
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    located: Located,
    full: np.ndarray,
    strong: Sequence[ConditionStructure],
) -> list[ConditionStructure]:
    """What a named effect's fit leaves of the located structure that it should have removed.

    An effect earns its parameters on held-out data by removing *some* of the
    mismatch; an effect outside the library (a back-EMF ripple in shaft
    angle, a speed reading that falls with the load) is often partly
    imitated by the nearest one in it. The named effect must also explain
    what was located: its residual, located again against the same floors,
    may keep no structure stronger than :data:`REMAINDER_SHARE` of the
    strongest before (nor :data:`UNEXPLAINED_Z`) and of a size (largest
    offset against the floor's rms) above :data:`REMAINDER_SIZE` and that
    share of the largest before, no rms above
    :data:`UNEXPLAINED_EXCESS` times the floor's that is more than half the
    plain model's, and no component periodic
    in shaft angle. The size is what keeps a converter's folded content out:
    sampled at 2 kHz behind a filter at fs/4 it leaves offsets of 0.25-0.4
    of the floor's rms that grow in z with the recording's length, not in size.
    """
    data = baseline.data
    rf, ra, _ = data.residuals(full, *data.whole_record)
    residuals = {"field": rf, "armature": ra}
    excess = {
        c: math.sqrt(float(np.nanmean(r**2)) / floors[c].variance_a2) for c, r in residuals.items()
    }
    worst = max(excess, key=lambda c: excess[c])
    if excess[worst] > UNEXPLAINED_EXCESS and excess[worst] > floors[worst].excess_ratio / 2:
        return [
            ConditionStructure(
                CURRENT_CHANNEL[worst],
                "rms",
                math.inf,
                (),
                (),
                (),
                f"{CURRENT_CHANNEL[worst]} residual {excess[worst]:.1f}x the noise floor "
                f"(plain model {floors[worst].excess_ratio:.1f}x)",
                excess[worst],
            )  # fmt: skip
        ]
    _, structure = locate(rec, residuals, floors, located.conditions)
    after = _strong(structure) + _strong(_periodic(rec, residuals, floors))
    top_z = max((s_.z for s_ in strong), default=0.0)
    top_size = max((s_.size for s_ in strong), default=0.0)
    left = [
        s_
        for s_ in after
        if s_.z >= max(UNEXPLAINED_Z, REMAINDER_SHARE * top_z)
        and s_.size >= max(REMAINDER_SIZE, REMAINDER_SHARE * top_size)
    ]
    return sorted(left, key=lambda s_: -s_.z)


def effect_size_v(baseline: Baseline, model: CandidateModel, full: np.ndarray) -> dict[str, float]:
    """How much an effect's fit changes each of its circuits, as an rms voltage at the winding.

    The rms difference between the plain model's residual and the effect's
    over the whole recording, times the winding's resistance.
    """
    data = baseline.data
    rf, ra, _ = data.residuals(full, *data.whole_record)
    out = {}
    for c, r in (("field", rf), ("armature", ra)):
        if c in model.circuits:
            est = baseline.field if c == "field" else baseline.armature
            d = baseline.residuals[c] - r
            out[c] = float(np.sqrt(np.nanmean(d**2))) * est.resistance_ohm
    return out


def alias_explains(
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    strong: Sequence[ConditionStructure],
    spectra: dict[str, VoltageSpectrum],
) -> tuple[ChainFinding, ...]:
    """``content_near_nyquist`` findings, if folding can cause every strong structure located.

    A structure's largest bin offset, as a voltage at the winding, is compared
    with the bound on the slow voltage error of the circuit's voltage channel
    (:class:`~observer.diagnosis.chain.VoltageSpectrum`): a motor effect of
    that size is within what the samples of this chain can tell.
    """
    if not strong:
        return ()
    by_channel: dict[str, list[ConditionStructure]] = {}
    for s_ in strong:
        circuit = _circuit(s_)
        if _offset_v(s_, baseline, floors) > spectra[circuit].alias_v:
            return ()
        by_channel.setdefault(circuit, []).append(s_)
    out = []
    for circuit, items in by_channel.items():
        words = "; ".join(s_.description.split(" (z =")[0] for s_ in items[:2])
        offset = max(_offset_v(s_, baseline, floors) for s_ in items)
        out.append(alias_finding(VOLTAGE_CHANNEL[circuit], spectra[circuit], offset, words))
    return tuple(out)


def voltage_spectra(
    rec: Any, linearity: Callable[[], Linearity | None] | None = None
) -> dict[str, VoltageSpectrum]:
    """Each circuit's :func:`~observer.diagnosis.chain.voltage_spectrum`, with the bound on the
    folded error of a spectrum whose top band is a line alone (a chopper's pulses, which
    bounds nothing: :attr:`VoltageSpectrum.line`) taken from the armature reading's fold
    instead: its peak (:meth:`~observer.estimation.linearity.Fold.peak_for`, scaled to the
    field's voltage for the field) where it was fitted and left in the reading; on the
    armature where it was taken out (:func:`without_folded_pulses`), the slow error the
    correction leaves (:attr:`~observer.estimation.linearity.Fold.residual_v`). The
    field's is never taken out (its steady levels cannot show a curve: each reads its own
    offset). Measured on the P-12 behind a filtered chopper at 5 kHz, whose fold (the pulses'
    5th harmonic on 4 fs) explained too little to be taken out: with no bound its slope at
    the reversals read as an ia residual against the speed (``unexplained``); at 10 kHz the
    field's offsets per level left its residual against the field current at z = 870."""
    spectra = {c: voltage_spectrum(rec[v], rec.dt) for c, v in VOLTAGE_CHANNEL.items()}
    if not any(s_.line for s_ in spectra.values()):
        return spectra
    result = linearity_of(rec, linearity)()
    if result is None or result.fold is None:
        return spectra
    fold, taken_out = result.fold, result.correction is not None
    return {
        c: dataclasses.replace(
            s_,
            alias_v=fold.residual_v
            if c == "armature" and taken_out
            else fold.peak_for(kernel_array(rec[VOLTAGE_CHANNEL[c]])),
        )
        if s_.line
        else s_
        for c, s_ in spectra.items()
    }


def front_end_findings(
    rec: Any,
    baseline: Baseline,
    spectra: dict[str, VoltageSpectrum],
    linearity: Callable[[], Linearity | None] | None = None,
) -> tuple[ChainFinding, ...]:
    """What the front end shows whatever the motor does: a missing filter, skewed channels,
    front ends nobody told whose mismatch could move an inductance (``linearity``: the
    armature reading's linearity test, where already known)."""
    linearity = linearity_of(rec, linearity)
    out = []
    for circuit, voltage in VOLTAGE_CHANNEL.items():
        shift, std = baseline.shifts.get(circuit, (0.0, 0.0))
        est = baseline.field if circuit == "field" else baseline.armature
        name = "Lf" if circuit == "field" else "La"
        folded = (
            _folded(rec, est, linearity)
            if circuit == "armature"
            else _field_folded(rec, baseline.armature, linearity)
        )
        v = kernel_array(rec[voltage])
        for found in (
            pwm_finding(voltage, v),
            folded,
            no_filter_finding(voltage, spectra[circuit]),
            # A reading that is not the voltage has no delay against the current to speak of
            # (the P-12 behind choppers sampled at their carrier: 1.1 samples "skew").
            None
            if folded is not None
            else averaged_finding(voltage, CURRENT_CHANNEL[circuit], shift)
            if circuit in baseline.averaged
            else skew_finding(voltage, CURRENT_CHANNEL[circuit], shift, std, rec.dt),
            front_end_finding(
                voltage, CURRENT_CHANNEL[circuit], est.front_end_std, est.inductance_h, name
            ),
            current_filter_finding(
                voltage,
                CURRENT_CHANNEL[circuit],
                v,
                kernel_array(rec[CURRENT_CHANNEL[circuit]]),
                rec.dt,
            ),
            # The field bridge's jumps are locked at 2, 5 and 10 kHz on 50 Hz mains and put
            # back between the samples (:mod:`observer.estimation.dealias`); the armature's
            # are not (a 6-pulse bridge's jumps come too close together). A chopper's edges
            # locked to the samples are its pulses folded, whose own findings
            # (``pulses_folded``, ``voltage_folded``) say what they do.
            locked_finding(voltage, v, rec.dt, _alias_of(rec, circuit))
            if circuit == "armature"
            and folded is None
            and made_by_a_bridge(v[: int(round(1.0 / rec.dt))], rec.dt, winding="armature")
            else None,
        ):
            if found is not None:
                out.append(found)
    return tuple(out)


def _alias_of(rec: Any, circuit: str) -> Callable[[], float]:
    """The aliasing factor of ``circuit``'s voltage filter as the estimator identifies it
    (:func:`~observer.estimation.estimate.voltage_filter`; not identified: the weakest filter
    in use, an RC at fs/4), computed when asked."""

    def factor() -> float:
        alias = voltage_filter(rec, circuit).alias
        return alias if alias is not None else alias_factor(None, 1.0 / rec.dt)

    return factor


def _folded(
    rec: Any, armature: CircuitEstimate, linearity: Callable[[], Linearity | None]
) -> ChainFinding | None:
    """``voltage_folded`` if the armature's voltage reads a curve of the voltage
    (:mod:`~observer.estimation.linearity`), where the test applies."""
    if not applies_to(armature.intersample):
        return None
    return folded_finding("va", linearity())


def _field_folded(
    rec: Any, armature: CircuitEstimate, linearity: Callable[[], Linearity | None]
) -> ChainFinding | None:
    """``voltage_folded`` on ``vf`` where the field is judged beside a folded armature
    (:func:`~observer.estimation.linearity.field_note`: a field chopper on the drive's PWM
    clock folds alike, and its steady voltage reads a gain and offset per level it cannot
    show; the P-12 behind choppers sampled at their 2 kHz carrier left the field's residual
    at z = 630-2300 against the field current, ``unexplained`` on a healthy motor)."""
    if not applies_to(armature.intersample):
        return None
    return field_folded_finding("vf", field_note(linearity(), kernel_array(rec["vf"]), rec.dt))


def _strong(structure: Sequence[ConditionStructure]) -> list[ConditionStructure]:
    return [s_ for s_ in structure if s_.z >= UNEXPLAINED_Z and s_.size >= UNEXPLAINED_SIZE]


#: Advice of a chain finding of kind ``jumps_between_samples``.
JUMPS_ADVICE = (
    "sample faster, or filter the voltage channels well below the Nyquist frequency, or measure "
    "the voltage averaged over each period, and configure the converter and chain in [chain]"
)


def switched_data(rec: Any, baseline: Baseline) -> tuple[FitData, list[tuple[str, float]]] | None:
    """The baseline's data with every interval across a voltage jump left out, or ``None``.

    Each circuit whose voltage the estimator reconstructs as smooth (``smooth``) and that
    jumps between samples often enough is simulated only between the transitions
    (``switched``); ``changed`` lists ``(voltage channel, share of intervals with a jump)``.
    """
    inputs = dict(baseline.data.inputs)
    changed: list[tuple[str, float]] = []
    for circuit, channel in (("armature", "va"), ("field", "vf")):
        inp = inputs.get(circuit)
        if inp is None or inp.model != "smooth":
            continue
        sw = find_switching(kernel_array(rec[channel]), rec.dt)
        if sw.transition_share < MIN_SWITCHED_SHARE:
            continue
        if circuit == "armature":
            problem = armature_problem(
                rec["va"], rec["ia"], rec["if"], rec["omega"], rec.dt, intersample="switched",
                fit_shift=False, shift=inp.shift,
            )  # fmt: skip
        else:
            problem = make_problem(
                kernel_array(rec["vf"]), kernel_array(rec["if"]), rec.dt, "switched",
                switching=sw, fit_shift=False, shift=inp.shift,
            )  # fmt: skip
        inputs[circuit] = problem.inp
        changed.append((channel, sw.transition_share))
    if not changed:
        return None
    return FitData(rec, baseline.full, baseline.context, inputs), changed


def _without_contradicted(
    switched: Callable[[], tuple[FitData, list[tuple[str, float]]] | None],
    floors: dict[str, NoiseFloor],
    cands: Candidates,
    selection: Selection,
    verdict: str,
    excluded: set[str],
) -> tuple[str, tuple[ChainFinding, ...], str]:
    """``verdict`` without the effects the samples between the voltage's jumps contradict.

    Where a converter's voltage jumps between samples and the estimator reconstructs it as
    smooth, the reconstruction errs across the jumps by an amount that follows the firing
    angle and the conduction (:func:`chain_explains`); an effect with a term in the operating
    point can fit that error. The verdict's fitted parameters (and each member's, for a pair)
    are scored again on the same held-out segments, each winding simulated only between the
    transitions (``switched``). There the simulation restarts from the measured current after
    every jump, so an effect that acts through the winding's slow response (a current
    sensor's offset: +4-7 % held out at 5 kHz, +0.1-0.2 % between the jumps) earns little,
    and that proves nothing; but an effect the samples between the jumps contradict,
    significantly (held-out likelihood ratio below -``MIN_HOLDOUT_LR``), was the
    reconstruction's, and the verdict is the best choice without it. Measured on the P-12
    behind the thyristor bridges at 2 kHz: a healthy motor's field_saturation +4.2 % held
    out, -3.1 % between the jumps; a 1 V brush drop +54 to +91 % there, a 2 % thermal rise
    +1 to +27 %. A real 1-2 % field saturation is no different on these recordings (their
    field current stands still, so nothing shows the flux curve): +3-4 % held out on the
    seed whose healthy recording gives +4.2 %, nothing on the others. Over 20 seeds at 2 kHz
    (6 s) it turned three wrong names into ``none`` (the healthy motor, configured or not, and
    the skewed channels, all on one duty cycle) and two of twenty 2 % thermal rises into
    ``none`` with this note: their armature terms had fitted the reconstruction as well
    (+9 % held out, -1 and -9 % between the jumps; their field's evidence, 27 %, is one slow
    trend, a few independent samples, and cannot carry the effect alone).

    ``switched``: :func:`switched_data` of the recording, on call. ``excluded``: effects
    already set aside (never chosen instead). Returns the verdict,
    ``jumps_between_samples`` findings, and a note ("" if nothing was contradicted).
    """
    between_jumps = switched()
    if between_jumps is None:
        return verdict, (), ""
    alt, changed = between_jumps
    scorer = HoldoutScorer(alt, cands, floors)
    evid = selection.evidence
    dropped: dict[str, dict[str, Any]] = {}  # contradicted between the jumps
    unsupported: list[str] = []  # a replacement that nothing between the jumps bears out
    between: dict[str, dict[str, Any]] = {}
    while verdict != NONE:
        keys = list(dict.fromkeys([verdict, *verdict.split("+")]))
        for k in keys:
            if k not in between:
                between[k] = scorer.evidence(k, NONE)
        bad = {k: between[k] for k in keys if between[k]["holdout_lr"] <= -MIN_HOLDOUT_LR}
        if dropped and not bad and not accepted(between[verdict]):
            # A replacement for a contradicted effect must show between the jumps: the one
            # it replaces was fitted to the jumps' reconstruction, which others fit too (the
            # healthy P-12 above: a current-sensor offset, +2.8 % held out, -0.5 % between).
            unsupported.append(verdict)
        elif not bad:
            break
        else:
            dropped.update(bad)
        singles = {k for k in [*dropped, *unsupported] if "+" not in k} | excluded
        gone = set(dropped) | set(unsupported)
        good = [n for n in selection.accepted_singles if n not in singles]
        pairs = [p for p in selection.pairs if p not in gone and not set(p.split("+")) & singles]
        verdict = _best_of(evid, good, pairs, cands)
    if not dropped:
        return verdict, (), ""
    notes = []
    for k, ev in dropped.items():
        gain = evid[k].get("holdout_gain_vs_plain", evid[k]["holdout_gain"])
        notes.append(
            f"{k} would earn its parameters ({100 * gain:+.1f} % held out), but the samples "
            f"between the voltage's jumps contradict it ({100 * ev['holdout_gain']:+.1f} % with "
            "the intervals across the jumps left out)"
        )
    if unsupported:
        notes.append(
            f"{' and '.join(unsupported)} would earn its parameters too, but nothing between the "
            "jumps bears it out"
        )
    names = " and ".join(dropped)
    note = (
        "; ".join(notes)
        + (": they fit" if len(dropped) + len(unsupported) > 1 else ": it fits")
        + " the reconstruction of the voltage across the jumps, not the motor (see the chain "
        "findings)"
    )
    findings = tuple(
        ChainFinding(
            channel,
            "jumps_between_samples",
            f"measurement chain: {channel} jumps between samples in {100 * share:.1f} % of the "
            f"intervals (a converter seen through a filter that lets its edges through), and "
            f"{names} fitted to the recording does worse between them: it is the "
            "reconstruction of the voltage across the jumps, not the motor",
            JUMPS_ADVICE,
        )
        for channel, share in changed
    )
    return verdict, findings, note


def chain_explains(
    rec: Any,
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    located: Located,
    strong: Sequence[ConditionStructure],
    switched: Callable[[], tuple[FitData, list[tuple[str, float]]] | None] | None = None,
) -> tuple[ChainFinding, ...]:
    """Chain findings, if leaving out the intervals across the voltage jumps removes the structure.

    A converter's voltage jumps between samples; filtered, the jumps pass
    the estimator's jump test and the voltage is reconstructed as smooth
    (``smooth``), but across them the reconstruction errs by an amount that
    follows the firing angle and the conduction, i.e. speed and load: located
    structure the motor does not cause. If the residual at the baseline's
    parameters, simulated only between the transitions (``switched``), shows
    no structure or window against the same floors, the structure is the
    chain's. Physics (a brush drop, a thermal rise, a ripple in shaft angle)
    stays in the residual between the jumps as well. ``switched``: :func:`switched_data` of
    ``rec``, where it is already at hand (else it is built).
    """
    between_jumps = switched() if switched is not None else switched_data(rec, baseline)
    if between_jumps is None:
        return ()
    alt, changed = between_jumps
    rf, ra, _ = alt.residuals(baseline.full, *alt.whole_record)
    mismatch, structure = locate(rec, {"field": rf, "armature": ra}, floors, located.conditions)
    if mismatch or _strong(structure):
        return ()
    words = "; ".join(s_.description.split(" (z =")[0] for s_ in strong[:2]) or "time windows"
    return tuple(
        ChainFinding(
            channel,
            "jumps_between_samples",
            f"measurement chain: {channel} jumps between samples in {100 * share:.1f} % of the "
            f"intervals (a converter seen through a filter that lets its edges through), and "
            f"the structure located ({words}) is gone when those intervals are left out: "
            "it is the reconstruction of the voltage across the jumps, not the motor",
            JUMPS_ADVICE,
        )
        for channel, share in changed
    )


def _refit_on_all_segments(
    cands: Candidates, data: FitData, key: str, *, n_particles: int, iterations: int, seed: int
) -> None:
    """Replace ``key``'s fit by one on the fit and held-out segments together."""
    fs, fe = cands.fit_segments
    hs, he = cands.holdout_segments
    all_s = np.concatenate([fs, hs])
    all_e = np.concatenate([fe, he])
    order = np.argsort(all_s)
    all_s, all_e = all_s[order], all_e[order]
    cands.fits[key] = fit_candidate(
        cands.models[key], data, all_s, all_e, cands.weights,
        n_particles=max(8, n_particles // 2), iterations=max(10, iterations // 2),
        rng=np.random.default_rng([seed, 99]),
    )  # fmt: skip


def _finding(
    key: str,
    baseline: Baseline,
    floors: dict[str, NoiseFloor],
    located: Located,
    cands: Candidates,
    evid: dict[str, dict[str, Any]],
) -> Finding:
    """One candidate's fit over the whole recording, with its evidence."""
    data, ctx, conds = baseline.data, baseline.context, located.conditions
    model = cands.models[key]
    f = cands.fits[key]
    rf, ra, k = data.residuals(f.full, *data.whole_record)
    eff = model.effect
    assert eff is not None
    values = {p.name: float(f.full[dk.FULL_PARAMS.index(p.name)]) for p in model.params}
    ch_circ = _main_circuit(model.circuits, baseline.rms, rf, ra)
    before = baseline.rms[ch_circ]
    after = float(np.sqrt(np.nanmean((rf if ch_circ == "field" else ra) ** 2)))
    ev = dict(evid[key])
    ev["rms_after"] = {
        "field": float(np.sqrt(np.nanmean(rf**2))),
        "armature": float(np.sqrt(np.nanmean(ra**2))),
    }
    ev["structure_after"] = {
        f"{s.channel}:{s.condition}": binned_structure(
            rf if s.channel == "if" else ra,
            conds[s.condition][0],
            floors["field" if s.channel == "if" else "armature"],
        )[0]
        for s in located.structure
    }
    corrected = {
        "field": {"R": float(f.full[dk.I_RF]), "L": float(f.full[dk.I_LF])},
        "armature": {"R": float(f.full[dk.I_RA]), "L": float(f.full[dk.I_LA]), "K": k},
    }
    return Finding(
        effect=key, explanation=eff.explanation, equation=eff.equation, params=values,
        magnitude=eff.magnitude(values, ctx), corrected=corrected, rms_before=before,
        rms_after=after, channel=CURRENT_CHANNEL[ch_circ], accepted=accepted(evid[key]),
        evidence=ev, full=f.full,
    )  # fmt: skip


# ------------------------------------------------------------------ diagnose


def diagnose(
    rec: Any,
    *,
    effects: Sequence[str] | None = None,
    n_particles: int = 24,
    iterations: int = 40,
    baseline_particles: int = 60,
    baseline_iterations: int = 60,
    max_fit_samples: int = 24000,
    combine: int = 3,
    seed: int = 0,
    compensate_input_noise: bool = True,
    progress: bool = False,
    path: str | None = None,
    chain: Any = None,
) -> Diagnosis:
    """Diagnose what the plain model misses in a recording.

    Parameters
    ----------
    rec : Recording
        With channels ``va, ia, vf, if, omega``.
    effects : sequence of str, optional
        Names from :data:`observer.diagnosis.effects.LIBRARY` to test (default: all).
    n_particles, iterations : int
        Swarm of each extension's fit (warm-started from the baseline).
    baseline_particles, baseline_iterations : int
        Swarm of the baseline estimates.
    max_fit_samples : int
        At most this many samples are fitted per candidate (the fit segments
        are thinned beyond it); the rest are held out for scoring.
    combine : int
        Pairs of the best this many accepted single effects are tried.
    seed : int
        Seed of all swarms.
    compensate_input_noise : bool
        Subtract the expected share of armature input-voltage noise from the
        extensions' (and the plain refit's) cost, with the noise variance read
        from the coloured part of the noise floor. Without it, output error
        overestimates ``La`` by several percent at 0.2 % sensor noise, and an
        effect that also delays the current (``sampling_skew``) is confounded.
    progress : bool
        Show a progress bar on stderr.
    chain : observer.config.ChainConfig, optional
        The measurement chain as far as it is known (the ``[chain]`` of a
        dcobserver config): the baseline and every extension use its
        intersample model and front ends; unknown parts are decided from the data.
    """
    rec.require("va", "ia", "vf", "if", "omega", path=path, purpose="a diagnosis")
    names = list(LIBRARY) if effects is None else list(effects)
    unknown = [n for n in names if n not in LIBRARY]
    if unknown:
        raise ValueError(f"unknown effect(s) {unknown}; expected some of {list(LIBRARY)}")
    split_segments(rec.n_samples, rec.dt, max_fit_samples)  # too short: say so before the fits
    rec, aliased = without_aliased_pulses(rec, chain, seed=seed)
    # The reading's linearity test, once: a reading whose fold is taken out was linear already
    # (and reads no curve without it), one without a fold is tested as it stays.
    linearity = linearity_of(rec)
    rec, folded = without_folded_pulses(rec, linearity)
    first_pass = None
    for keep_delay in (False, True):
        baseline = fit_baseline(
            rec, n_particles=baseline_particles, iterations=baseline_iterations, seed=seed,
            chain=chain, keep_delay=keep_delay,
        )  # fmt: skip
        floors = noise_floors(baseline)
        located = locate_mismatch(rec, baseline, floors)
        segments = split_segments(baseline.data.n, rec.dt, max_fit_samples)
        bar = _progress(len(names) + 1 + combine, progress)
        cands = fit_candidates(
            baseline, floors, names, segments, n_particles=n_particles, iterations=iterations,
            seed=seed, compensate_input_noise=compensate_input_noise, bar=bar,
        )  # fmt: skip
        scorer = HoldoutScorer(baseline.data, cands, floors)
        selection = select_effects(
            cands, scorer, names, baseline.context, combine=combine, n_particles=n_particles,
            iterations=iterations, seed=seed, bar=bar,
        )  # fmt: skip
        bar.close()
        outcome = decide_verdict(
            rec, baseline, floors, located, cands, selection, names, n_particles=n_particles,
            iterations=iterations, seed=seed, linearity=linearity,
        )  # fmt: skip
        if keep_delay or not outcome.chain_read:
            break
        # What earned its parameters was set aside only as the chain's own reading (currents
        # read after their voltages): diagnosed again with the voltages' delays in the plain
        # model, so that a motor effect under that skew is judged beside it, not against it.
        first_pass = outcome
    if first_pass is not None:
        outcome = dataclasses.replace(
            outcome,
            description=f"{outcome.description}; diagnosed with the voltages' delays the "
            f"estimator fitted kept in the plain model, since {first_pass.chain_read}",
            chain=_first_of_each((*outcome.chain, *first_pass.chain)),
        )
    taken_out = tuple(f for f in (aliased, folded) if f is not None)
    outcome = dataclasses.replace(outcome, chain=_first_of_each((*taken_out, *outcome.chain)))
    plain = cands.fits[NONE]
    plain_refit = {
        "field": {"R": float(plain.full[dk.I_RF]), "L": float(plain.full[dk.I_LF])},
        "armature": {
            "R": float(plain.full[dk.I_RA]),
            "L": float(plain.full[dk.I_LA]),
            "K": plain.k,
        },
    }
    after: dict[str, np.ndarray] = {}
    if outcome.findings:
        rf1, ra1, _ = baseline.data.residuals(outcome.findings[0].full, *baseline.data.whole_record)
        after = {"field": rf1, "armature": ra1}
    return Diagnosis(
        verdict=outcome.verdict,
        description=outcome.description,
        baseline={"field": baseline.field, "armature": baseline.armature},
        baseline_rms=baseline.rms,
        floors=floors,
        mismatch=located.mismatch,
        structure=outcome.structure,
        findings=outcome.findings,
        context=baseline.context,
        baseline_full=baseline.full,
        baseline_k=baseline.k,
        residuals_before=dict(baseline.residuals),
        residuals_after=after,
        conditions=located.conditions,
        plain_refit=plain_refit,
        chain=outcome.chain,
        intersample={
            c: {"model": inp.model, "shift_samples": inp.shift}
            for c, inp in baseline.data.inputs.items()
        },
    )


def _degenerate(model: CandidateModel, fit: Fit) -> bool:
    """Whether a member of a pair sits at its neutral value (the pair is then a single effect).

    Only magnitude parameters count (time constants, searched on a log scale,
    shape an effect but do not make it present).
    """
    effect = model.effect
    if effect is None or len(effect.members) < 2:
        return False
    for member in effect.members:
        names = {q.name for q in member.parameters(model.ctx)}
        moved = False
        for p in model.params:
            if p.name in names and not p.log:
                value = fit.full[dk.FULL_PARAMS.index(p.name)]
                moved |= bool(abs(value - p.neutral) > 0.01 * (p.high - p.low))
        if not moved:
            return True
    return False


def _main_circuit(
    circuits: tuple[str, ...], before: dict[str, float], rf: np.ndarray, ra: np.ndarray
) -> str:
    if len(circuits) == 1:
        return circuits[0]

    def gain(r: np.ndarray, rms: float) -> float:  # a residual of zero cannot shrink
        return 1 - float(np.sqrt(np.nanmean(r**2))) / rms if rms > 0 else 0.0

    return "field" if gain(rf, before["field"]) > gain(ra, before["armature"]) else "armature"


def _describe(
    verdict: str,
    findings: Sequence[Finding],
    structure: Sequence[ConditionStructure],
    mismatch: Sequence[Mismatch],
    floors: dict[str, NoiseFloor],
) -> str:
    if verdict == NONE:
        return "the plain model is adequate: no extension earns its parameters on held-out data"
    best = next(f for f in findings if f.effect == verdict)
    return (
        f"{verdict}: {best.explanation}; held-out improvement "
        f"{100 * best.evidence.get('holdout_gain_vs_plain', best.evidence['holdout_gain']):.1f} %, "
        f"rms of {best.channel} {best.rms_before:.4g} -> {best.rms_after:.4g} A"
    )


class _NoBar:
    def update(self, n: int = 1) -> None: ...

    def set_description(self, text: str) -> None: ...

    def close(self) -> None: ...


def _progress(total: int, show: bool) -> Any:
    if not show:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, file=sys.stderr, unit="model", leave=False)
