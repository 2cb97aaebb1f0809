"""The sliding-window observer: re-estimates the windings every hop from the ring buffer.

Windows are laid on the *data* time axis, not the wall clock: window ``k``
holds the samples with ``end_k - window < t <= end_k``, ``end_k = anchor +
window + k * hop`` where ``anchor`` is the first sample's time. Each window's
swarm draws from a generator seeded with ``(seed, k, circuit)``, and the warm
start depends only on earlier windows, so a replay of a log gives the same
numbers as the live daemon did (as long as the live daemon kept up: a window
it had to skip because it fell behind is counted in ``late``).

Each window's fits are measurements for the tracker
(:class:`observer.service.tracker.MotorTracker`): the values published are the
tracked state with its std, the window's own fit rides along as ``raw``. A
parameter whose relative std in this window exceeds its
``[observer.quality]`` limit (e.g. ``Lf`` under a constant field voltage), or
a window the estimator says its model does not describe, is no evidence: the
tracker carries the parameter forward (``quality = "held"``). Confirmed changes
and a tachometer that reads low (:mod:`observer.service.speed`) are events;
the winding temperatures and the EMF speed come from the tracked state.

Warm start: each circuit's swarm starts from the tracked ``(R, L)``, most
particles inside ``around(R, L, factor)`` of the full data-derived range and a
fraction ``explore_fraction`` spread over the whole range, so a real change is
caught. While ``L`` is not tracked (a field whose voltage has not stepped: the
window barely depends on ``L``), the last window's fitted ``L`` stands in once
``R`` is, instead of a cold swarm in every window. ``factor`` shrinks while the
fits agree with the tracked state and widens (and the next window runs the
cold, larger swarm) when the fit degrades or differs by more than
``[observer.agree]``. Once it has shrunk to ``min_range_factor`` the search is
settled: a window is polished from the tracked state without a swarm
(:func:`observer.estimation.stages.settled_stage`), and its swarm runs only
when that fit is degraded (``degrade_ratio`` times the recent fits' median rms).

Measurement chain: each circuit's intersample model (how the voltage behaves
between samples, :mod:`observer.estimation.intersample`) and the relative delay
of its voltage channel are properties of the drive and its data acquisition,
not of a window. Unless ``[chain]`` fixes them, the first
``chain_windows`` estimated windows decide them from the data (each window
votes for a model and fits the delay); then they are held, and every later
window estimates only ``R``, ``L`` (and ``K``), more precisely. A window whose
model cannot describe it (``describes_window`` false) moves nothing.

Windows with a gap, a time jump, a stuck channel or too few samples are
skipped and counted by reason; nothing here raises into the caller's loop.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
import statistics
import time
from collections import Counter, deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from observer.config import ChainConfig, ObserverConfig
from observer.estimation import (
    CIRCUIT_CHANNELS,
    CircuitEstimate,
    EstimationError,
    SearchRange,
    armature_search_range,
    estimate_armature,
    estimate_field,
    field_search_range,
)
from observer.estimation.estimate import (
    not_described,
    simex_noise,
    with_field_fold,
    with_linearity,
)
from observer.estimation.filter_id import (
    IDENTIFIED_WINDINGS,
    FilterFit,
    identify_voltage_filter,
)
from observer.estimation.frontend import applied_mismatch, gain_tolerances, winding_front_ends
from observer.estimation.linearity import (
    RETEST_SECONDS,
    WATCH_SECONDS,
    Fold,
    Linearity,
    LinearityAccumulator,
    applies_to,
    field_note,
    made_by_a_bridge,
)
from observer.estimation.motor import MotorParameters
from observer.estimation.result import kphi, with_gain_tolerance
from observer.service.circuit_worker import CircuitWorker, WorkerFailed
from observer.service.ringbuffer import RingBuffer, Window
from observer.service.speed import SpeedEstimate, TachometerCheck, emf_speed
from observer.service.tracker import (
    LOCATION,
    PARAMETERS,
    Evidence,
    MotorTracker,
    TrackerStep,
    winding_temperature,
)

log = logging.getLogger(__name__)

#: Tries at identifying an untold voltage filter from windows with too few jumps.
FILTER_TRIES = 20

#: An untold voltage filter is identified in a thread beside the windows (0.5-0.6 s of CPU
#: a winding at 10 kHz; run in the observer's thread it held up the windows behind it,
#: and a converter-fed daemon's first windows then waited up to a second). Its result is
#: used from the window this long (s) after the one it was identified from, waiting for it
#: there if it is not ready: live and replayed windows use it from the same window, so a
#: replay still gives the live numbers.
FILTER_DUE_S = 1.5

_NS = 1_000_000_000
CIRCUIT_PARAMS = {"field": ("R", "L"), "armature": ("R", "L", "K")}
#: circuit -> {letter: tracked parameter name}
CIRCUIT_NAMES = {
    c: {p: name for name, (cc, p) in LOCATION.items() if cc == c} for c in ("field", "armature")
}
_CIRCUIT_INDEX = {"field": 0, "armature": 1}


@dataclass
class _Search:
    """Warm-start state of one circuit's swarm."""

    factor: float | None = None  # None: next window runs cold over the full range
    warm: bool = False  # whether the last window was warm-started
    # The last window's fitted L: the warm start's L while none is tracked (a
    # field before its voltage steps), where the cost barely depends on L.
    last_l: float | None = None
    rms_history: deque[float] = field(default_factory=lambda: deque(maxlen=20))


@dataclass
class _ChainState:
    """What the first windows found about a circuit's measurement chain."""

    model: str | None = None  # decided intersample model (None: still deciding)
    shift: float = 0.0  # decided relative delay of the voltage (sample periods)
    # Untold front ends: the decided size of the channels' commonest mismatch (None: none).
    mismatch: float | None = None
    # Untold front ends: the voltage filter identified from the converter's jumps, and the
    # windows since the chain was decided (tries are spaced by them).
    voltage_filter: FilterFit | None = None
    filter_windows: int = 0
    # An identification under way: its result and the window index from which it is used.
    pending: tuple[Future[FilterFit], int] | None = None
    votes: Counter[str] = field(default_factory=Counter)
    shifts: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    mismatches: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    def filter_tries(self, chain_windows: int) -> int:
        """Identifications tried so far: one every ``chain_windows`` windows from the first."""
        return (self.filter_windows - 1) // chain_windows + 1

    def record(self, est: CircuitEstimate) -> None:
        model = est.intersample
        self.votes[model] += 1
        if est.shift_std > 0 and math.isfinite(est.shift_std):
            self.shifts.setdefault(model, []).append((est.shift_samples, est.shift_std))
        if math.isfinite(est.mismatch_size) and math.isfinite(est.mismatch_shift):
            self.mismatches.setdefault(model, []).append((est.mismatch_size, est.mismatch_shift))

    def decide(self, noise_share: Callable[[], float] | None = None) -> None:
        """Majority model; its windows' delays averaged by inverse variance. Untold front
        ends: the windows' median mismatch of the channels, less what the voltage's noise
        makes of it where it would be corrected for (``noise_share()``, see
        :func:`~observer.estimation.estimate.with_learned_mismatch`), and where it still is
        (:func:`~observer.estimation.frontend.applied_mismatch`), the median of the delays
        that go with it."""
        model = self.votes.most_common(1)[0][0]
        pairs = self.shifts.get(model, [])
        if pairs:
            weights = np.array([1.0 / s**2 for _, s in pairs])
            self.shift = float(np.dot(weights, [v for v, _ in pairs]) / weights.sum())
        sizes = self.mismatches.get(model, [])
        if sizes:
            self.mismatch = float(np.median([a for a, _ in sizes]))
            if applied_mismatch(self.mismatch) and noise_share is not None:
                self.mismatch -= noise_share()
            if applied_mismatch(self.mismatch):
                self.shift = float(np.median([d for _, d in sizes]))
        self.model = model

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "shift_samples": self.shift if self.model is not None else None,
            "mismatch": self.mismatch if self.model is not None else None,
            "voltage_filter": (
                self.voltage_filter.to_dict() if self.voltage_filter is not None else None
            ),
            "votes": dict(self.votes),
        }


@dataclass(frozen=True)
class WindowResult:
    """What one window produced: an estimate (JSON-ready dict) or a skip reason."""

    index: int
    t0_ns: int
    t1_ns: int
    estimate: dict[str, Any] | None
    skip_reason: str = ""
    arrival_ns: int = 0  # host monotonic time the window's last sample reached the ring
    events: tuple[dict[str, Any], ...] = ()  # changes and tachometer alarms of this window


def check_window(window: Window, max_gap_periods: float) -> tuple[str, float]:
    """``("", period_s)`` if the window is usable, else ``(reason, period_s)``.

    Reasons: ``"too_few_samples"``, ``"time_jump"`` (time not increasing),
    ``"gap"`` (a sample interval above ``max_gap_periods`` median periods),
    ``"stuck:<channel>"`` (a channel repeating one value for more than a tenth
    of the window, at least 20 samples: a frozen sensor or a stale register).
    """
    n = len(window)
    if n < 20:
        return "too_few_samples", math.nan
    d = np.diff(window.t_ns)
    if np.any(d <= 0):
        return "time_jump", math.nan
    period = float(np.median(d))
    if float(d.max()) > max_gap_periods * period:
        return "gap", period / _NS
    for name, values in window.signals.items():
        if np.isnan(values[0]):
            continue  # a channel the source does not provide
        if np.any(np.isnan(values)):
            return f"missing:{name}", period / _NS
        if _longest_repeat(values) > max(20, n // 10):
            return f"stuck:{name}", period / _NS
    return "", period / _NS


def _longest_repeat(values: np.ndarray) -> int:
    """Length of the longest run of identical consecutive samples (a frozen sensor)."""
    same = np.concatenate(([False], values[1:] == values[:-1], [False]))
    edges = np.flatnonzero(same[1:] != same[:-1])
    if edges.size == 0:
        return 1
    return int((edges[1::2] - edges[::2]).max()) + 1


def _decimated(values: np.ndarray, k: int, *, sample: bool) -> np.ndarray:
    """Every ``k``-th sample (``sample``) or the mean of each ``k`` samples."""
    if k == 1:
        return values
    n = (values.size // k) * k
    if sample:
        return values[:n:k].copy()
    return values[:n].reshape(-1, k).mean(axis=1)


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


#: What a circuit's estimate may raise that fails its window, not the observer.
_ESTIMATION_ERRORS = (EstimationError, ArithmeticError, ValueError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class _Prepared:
    """One circuit's estimator arguments for a window (what the worker is sent)."""

    circuit: str
    signals: dict[str, np.ndarray]
    dt: float
    kwargs: dict[str, Any]
    warm: bool
    index: int


def _identified(fit: FilterFit | None) -> str | None:
    return fit.best if fit is not None and fit.alias is not None else None


def run_estimator(prep: _Prepared) -> CircuitEstimate:
    """The circuit's estimate of ``prep`` (here, or in :mod:`.circuit_worker`'s process)."""
    s = prep.signals
    if prep.circuit == "field":
        return estimate_field(s["vf"], s["if"], prep.dt, **prep.kwargs)
    return estimate_armature(s["va"], s["ia"], s["if"], s["omega"], prep.dt, **prep.kwargs)


#: While the tachometer reads low (its alarm on, or the window suspect) the armature's window
#: fits all use a wrong speed: K takes most of it, but Ra and La move too (a tachometer losing
#: 10 % moved the configured converter-fed P-12's La by 2.8 % in windows weighed by their
#: calibrated variance, and the tracker announced a rise). None of them is learnt meanwhile.
ARMATURE_MISLED = frozenset({"Ra", "La", "K"})


class SlidingWindowObserver:
    """Estimates field and armature over sliding windows of a :class:`RingBuffer`.

    Parameters
    ----------
    ring : RingBuffer
    config : ObserverConfig
    clock : callable, optional
        Monotonic nanoseconds (for the elapsed time of each estimate).
    """

    def __init__(
        self,
        ring: RingBuffer,
        config: ObserverConfig,
        *,
        chain: ChainConfig | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
        parallel: bool = False,
    ) -> None:
        self.ring = ring
        self.config = config
        self.chain = chain if chain is not None else ChainConfig()
        self._clock = clock
        self.window_ns = int(round(config.window_s * _NS))
        self.hop_ns = int(round(config.hop_s * _NS))
        self.circuits = ("field", "armature") if config.circuits == "both" else (config.circuits,)
        self._search = {c: _Search() for c in self.circuits}
        limits = {name: config.quality.limits(c)[p] for name, (c, p) in LOCATION.items()}
        self.tracker = MotorTracker(
            config.tracker, window_s=config.window_s, hop_s=config.hop_s, limits=limits
        )
        self.tachometer = TachometerCheck(config.speed, config.hop_s)
        self._chain_state = {c: _ChainState() for c in self.circuits}
        self._anchor_ns: int | None = None
        self.next_index = 0
        self.counts: Counter[str] = Counter()
        self.last_skip_reason = ""
        self.warnings: set[str] = set()
        self.last_estimate: dict[str, Any] | None = None
        self._resume_index = 0
        # The armature's estimate in a second process (:mod:`.circuit_worker`), started by
        # start_worker (or at the first window with both circuits); None: both here.
        self._parallel = parallel and len(self.circuits) == 2
        self._worker: CircuitWorker | None = None
        self.worker_windows = 0  # windows whose armature the worker estimated
        self.worker_failures = 0
        # The untold voltage filters' identification (FILTER_DUE_S), started when first needed.
        self._identifier: ThreadPoolExecutor | None = None
        self._filter_due = max(1, math.ceil(FILTER_DUE_S / config.hop_s - 1e-9))
        # The armature voltage reading's linearity over the last WATCH_SECONDS of contiguous
        # samples (:mod:`observer.estimation.linearity`), tested every RETEST_SECONDS.
        self._linearity: LinearityAccumulator | None = None
        self._linearity_end_ns: int | None = None
        self._linearity_tested_s = 0.0
        self.voltage_linearity: Linearity | None = None
        # A test under way beside the windows: its result and the window index it is used from
        # (as for the filter identification, so that a replay gives the live numbers).
        self._linearity_pending: tuple[Future[Linearity | None], int] | None = None
        # A bridge made the armature's voltage (seen once, a drive keeps its converter): its
        # reading is not tested for a curve (see _watch_linearity).
        self._armature_bridge = False
        # How every armature window so far read its voltage (described or not: the chain's
        # votes count only described ones), for a later window's question of whether the
        # armature's voltage is measured (_armature_measured).
        self._armature_reads: Counter[str] = Counter()
        self._armature_first: str | None = None

    def start_worker(self, wait_s: float = 0.0) -> bool:
        """Start the circuit worker (if ``parallel`` and not yet started), waiting up to
        ``wait_s`` for it to load its kernels; whether it is ready. Windows before then
        estimate both circuits here."""
        if not self._parallel:
            return False
        if self._worker is None:
            self._worker = CircuitWorker()
        return self._worker.wait_ready(wait_s) if wait_s > 0 else self._worker.ready()

    def close(self) -> None:
        """Stop the circuit worker, if one was started (the observer can go on without it),
        and the filter identification's thread (an identification or linearity test under
        way is dropped)."""
        if self._worker is not None:
            self._worker.close()
            self._worker = None
        self._parallel = False
        if self._identifier is not None:
            self._identifier.shutdown(wait=True, cancel_futures=True)
            self._identifier = None
        for state in self._chain_state.values():
            state.pending = None
        self._linearity_pending = None

    @property
    def parallel_state(self) -> str:
        """``off``, ``starting`` (the worker loads its kernels), ``on`` or ``failed``."""
        if self._worker is None:
            return "failed" if self.worker_failures else "off"
        if self._worker.closed:
            return "failed"
        return "on" if self._worker.ready() else "starting"

    def _worker_failed(self) -> None:
        """The worker died, stopped answering, or was left busy (a window ended by an
        unexpected error with its answer pending): stop it; both circuits run here."""
        self.worker_failures += 1
        if self._worker is not None:
            self._worker.close()
        self._worker = None
        self._parallel = False

    # ------------------------------------------------------------------ schedule

    def window_end_ns(self, index: int) -> int | None:
        """End time (ns) of window ``index``, or None before the first sample."""
        if self._anchor_ns is None:
            return None
        return self._anchor_ns + self.window_ns + index * self.hop_ns

    def _ensure_anchor(self) -> bool:
        if self._anchor_ns is None:
            first = self.ring.latest(self.ring.capacity)
            if first is None:
                return False
            self._anchor_ns = int(first.t_ns[0])
        return True

    def next_due_ns(self) -> int | None:
        """Data time the ring must reach before the next window can run."""
        if not self._ensure_anchor():
            return None
        return self.window_end_ns(self.next_index)

    def process_ready(self, *, live: bool = False) -> Iterator[WindowResult]:
        """Run every window whose end the data has reached, yielding each result at once.

        A generator, so a caller publishes each estimate as soon as it is made,
        even while the data keeps arriving. With ``live``, when the observer has
        fallen more than ``max_lag_windows`` behind the data it jumps to the
        newest window (skipped windows counted in ``late``) so estimates stay current.
        """
        if not self._ensure_anchor():
            return
        while True:
            last = self.ring.last_t_ns
            end = self.window_end_ns(self.next_index)
            assert end is not None and self._anchor_ns is not None
            if last is None or last < end:
                if last is not None and end - last > self.window_ns + 10 * _NS:
                    # Time went far backwards (device clock reset): start again from the data.
                    self._reanchor(last, "time_jump")
                    continue
                return
            if live:
                behind = (last - end) // self.hop_ns
                if behind > self.config.max_lag_windows:
                    self.counts["late"] += int(behind)
                    self.next_index += int(behind)
                    continue
            self._resume_index = 0
            result = self._run_window(self.next_index, end)
            self.next_index = max(self.next_index + 1, self._resume_index)
            yield result

    def _reanchor(self, t_ns: int, reason: str) -> None:
        """Move the schedule so the next window is the first full one after ``t_ns``."""
        assert self._anchor_ns is not None
        self.counts[f"skipped:{reason}"] += 1
        self.last_skip_reason = reason
        k = math.ceil((t_ns - self._anchor_ns) / self.hop_ns)
        if k < self.next_index:
            self._anchor_ns = t_ns - self.next_index * self.hop_ns
        else:
            self.next_index = k

    # ------------------------------------------------------------------ one window

    def _run_window(self, index: int, end_ns: int) -> WindowResult:
        t0 = end_ns - self.window_ns
        window = self.ring.between(t0, end_ns)
        if window is None or len(window) < 20:
            # (Almost) nothing in this window: if data resumes later, move the
            # schedule to the first window starting after it, not hop by hop.
            last = self.ring.last_t_ns
            after = None if last is None else self.ring.between(end_ns, last)
            if after is not None and len(after) and self._anchor_ns is not None:
                first_after = int(after.t_ns[0])
                self._resume_index = math.ceil((first_after - self._anchor_ns) / self.hop_ns)
            return self._skip(index, t0, end_ns, "gap" if window is not None else "no_data")
        reason, period_s = check_window(window, self.config.max_gap_periods)
        if reason:
            return self._skip(index, t0, end_ns, reason)
        expected = self.window_ns / (period_s * _NS)
        if len(window) < 0.9 * expected:
            return self._skip(index, t0, end_ns, "too_few_samples")
        started = self._clock()
        out: dict[str, Any] = {
            "index": index,
            "t_ns": int(end_ns),
            "window": [int(t0), int(end_ns)],
            "n_samples": len(window),
            "sample_rate_hz": 1.0 / period_s,
        }
        signals = dict(window.signals)
        self._watch_linearity(window, period_s, index)
        fold = self._fold()
        if fold is not None:
            # The converter's pulses folded onto the reading: taken out for everything that
            # reads the armature voltage (its estimate, the EMF speed).
            signals["va"] = signals["va"] - fold.of_samples(signals["va"], period_s)
        flags: list[str] = []
        fits: dict[str, CircuitEstimate | None] = {}
        # Each circuit's estimate from the state before this window: prepared first, run
        # (the armature's in the worker, if one is ready, while the field's runs here),
        # then each circuit's own state updated in order, as one after the other would.
        prepared: dict[str, _Prepared | Exception] = {}
        for circuit in self.circuits:
            if any(np.isnan(signals[c][0]) for c in CIRCUIT_CHANNELS[circuit]):
                continue  # the source lacks a channel this circuit needs
            try:
                prepared[circuit] = self._prepare_circuit(circuit, index, signals, period_s)
            except _ESTIMATION_ERRORS as exc:
                prepared[circuit] = exc
        remote = self._submit_remote(prepared)
        for circuit, prep in prepared.items():
            try:
                if isinstance(prep, Exception):
                    raise prep
                fit = self._remote_result(prep) if circuit == remote else run_estimator(prep)
                self._finish_circuit(prep, fit)
                read = fit.intersample
                fit = self._with_linearity(circuit, fit, signals, period_s)
                if circuit == "armature":
                    self._armature_reads[read] += 1
                    self._armature_first = self._armature_first or read
                if circuit == "field":
                    fit = with_field_fold(fit, self._fold(), signals["vf"], period_s)
                fits[circuit] = with_gain_tolerance(fit, gain_tolerances(self.chain, circuit))
            except _ESTIMATION_ERRORS as exc:
                self.counts[f"{circuit}_failed"] += 1
                flags.append(f"{circuit}: {exc}")
                fits[circuit] = None
        if not fits:
            return self._skip(index, t0, end_ns, "no_circuit_channels")
        # The EMF speed from the state *before* this window: a window must not
        # vouch for itself (a tachometer reading low would teach K its error).
        speed = self._emf_speed(signals, period_s, fits.get("armature"))
        suspect, tach_event = self.tachometer.update(int(end_ns), speed)
        distrust = ARMATURE_MISLED if self.tachometer.distrusts_k(suspect) else frozenset()
        step = self.tracker.step(
            int(end_ns), self._evidence(fits), loss_w=self._copper_loss(signals, period_s, fits),
            distrust=distrust,
        )  # fmt: skip
        for circuit, est in fits.items():
            out[circuit] = self._circuit_output(circuit, est, step)
            if circuit == "armature":
                out[circuit].update(_kphi(out[circuit], signals["if"]))
            if est is None:
                out[circuit]["error"] = next(
                    (f.split(": ", 1)[1] for f in flags if f.startswith(f"{circuit}: ")), ""
                )
        temperature = self._temperatures(step)
        if temperature:
            out["temperature"] = {
                circuit: {"C": temp_c, "std": std_c}
                for circuit, (temp_c, std_c) in temperature.items()
            }
        out["speed"] = self._speed_output(speed, signals)
        events = [self._change_event(c) for c in step.changes]
        if tach_event is not None:
            events.append(tach_event)
        if events:
            self._restart_linearity()
        for note in step.notes:
            log.info("window %d: %s", index, note)
        flags += step.notes
        out["events"] = events
        out["elapsed_ms"] = (self._clock() - started) / 1e6
        out["flags"] = flags
        self.counts["estimated"] += 1
        self.counts["events"] += len(events)
        self.last_estimate = out
        return WindowResult(
            index, t0, end_ns, out, arrival_ns=int(window.arrival_ns[-1]), events=tuple(events)
        )

    def _watch_linearity(self, window: Window, period_s: float, index: int) -> None:
        """Add the window's new armature samples to the linearity test; start a test when
        due (in the identification thread, its result used from a fixed later window)."""
        if "armature" not in self.circuits or self._armature_bridge:
            return
        self._collect_linearity(index)
        channels = [window.signals[c] for c in ("va", "ia", "if", "omega")]
        if any(np.isnan(x[0]) for x in channels):
            return
        # Looked for in every window while one would be held (no result yet, or a curve),
        # else in each test's last window: a chopper's voltage read as linear need not pay
        # the look (~1 ms a window at 10 kHz) again every hop.
        result = self.voltage_linearity
        if (result is None or not result.linear) and self._bridge_seen(channels[0], period_s):
            return
        acc = self._linearity
        last = self._linearity_end_ns
        t = window.t_ns
        if (
            acc is None
            or not math.isclose(acc.dt, period_s, rel_tol=1e-3)
            or last is None
            or int(t[0]) > last + int(1.5 * period_s * _NS)  # not contiguous: start again
        ):
            acc = self._linearity = LinearityAccumulator(period_s, keep_seconds=WATCH_SECONDS)
            self._linearity_tested_s = 0.0
            last = None
        new = slice(None) if last is None else slice(int(np.searchsorted(t, last, "right")), None)
        va, ia, i_f, omega = (np.asarray(x[new], dtype=np.float64) for x in channels)
        if va.size:
            acc.add(va, ia, i_f, omega)
            self._linearity_end_ns = int(t[-1])
        if (
            acc.added_seconds - self._linearity_tested_s >= RETEST_SECONDS
            and self._linearity_pending is None
        ):
            if result is not None and result.linear and self._bridge_seen(channels[0], period_s):
                return
            self._linearity_tested_s = acc.added_seconds
            if self._identifier is None:
                self._identifier = ThreadPoolExecutor(1, thread_name_prefix="dcobserver-filter")
            job = self._identifier.submit(acc.snapshot(armature=True))
            self._linearity_pending = (job, index + self._filter_due)

    def _fold(self) -> Fold | None:
        """The converter's pulses folded onto the armature voltage's reading, to be taken out of
        its samples (:attr:`~observer.estimation.linearity.Linearity.correction`), or None."""
        result = self.voltage_linearity
        if result is None or self._armature_bridge:
            return None
        return result.correction

    def _bridge_seen(self, va: np.ndarray, period_s: float) -> bool:
        """Whether the window's armature voltage ``va`` shows a bridge's ripple; then the
        linearity test stops for good. It was built for a chopper's pulses sampled in step with
        the ADC. A bridge's jumps are put back between the samples (and their fold with them),
        and what the test finds on its voltage is the operating point's, not the reading's: a
        5 % step of K or a tachometer losing 10 % read as a curve of 0.6-0.8 % of the largest
        voltage 5-7 s later, and held the armature's windows for as long as the step stayed in
        the tested stretch."""
        if not made_by_a_bridge(np.asarray(va, dtype=np.float64), period_s, winding="armature"):
            return False
        self._armature_bridge = True
        self._restart_linearity()
        self.voltage_linearity = None
        return True

    def _restart_linearity(self) -> None:
        """After a change of the motor or of its tachometer: the linearity test starts on the
        samples after it. Samples from both sides under one set of parameters leave an error
        that follows the operating point, which a curve of the voltage partly explains; a
        result that says so (not linear) is dropped with them."""
        self._linearity = None
        self._linearity_pending = None
        if self.voltage_linearity is not None and not self.voltage_linearity.linear:
            self.voltage_linearity = None

    def _collect_linearity(self, index: int) -> None:
        """From its window on, the linearity test's result (waiting for it)."""
        if self._linearity_pending is None or index < self._linearity_pending[1]:
            return
        job, _ = self._linearity_pending
        self._linearity_pending = None
        result = job.result()
        if result is None:
            return
        if self.voltage_linearity is None or result.linear != self.voltage_linearity.linear:
            log.log(
                logging.INFO if result.linear else logging.WARNING,
                "armature voltage reading over the last %.0f s: %s (a curve of %.2g V rms, "
                "%.2g %% of the largest voltage, explains %.0f %% of the slow equation error)%s",
                result.seconds, "linear" if result.linear else "NOT linear", result.curve_v,
                100 * result.size, 100 * result.share,
                "" if result.linear else "; its windows are held",
            )  # fmt: skip
        fold = result.correction
        before = self.voltage_linearity.correction if self.voltage_linearity is not None else None
        if fold is not None and before is None:
            log.info(
                "armature voltage reading: a converter's pulses fold onto it as a curve "
                "periodic in the voltage (period %.0f V, %.2g V rms, %.0f %% of the slow "
                "equation error); taken out of the samples before the armature is estimated",
                fold.period_v, fold.rms_v, 100 * fold.share,
            )  # fmt: skip
        self.voltage_linearity = result

    def _with_linearity(
        self, circuit: str, est: CircuitEstimate, window: dict[str, np.ndarray], period_s: float
    ) -> CircuitEstimate:
        """``est``, not describing its window while the armature's voltage reading follows a
        curve of the voltage (and, for the field, its voltage shows no mains ripple: a
        chopper's, :func:`~observer.estimation.linearity.field_note`)."""
        result = self.voltage_linearity
        if result is None and not self._armature_bridge and self._armature_measured(circuit, est):
            # Not tested yet: a measured voltage that no bridge made may be a chopper's
            # sampled in step, confidently wrong in every window; held until the test says.
            # (A bridge's voltage is never tested: a window of it without ripple, the drive
            # at rest, is not a chopper's.)
            return not_described(est, self._untested_note(circuit, window, period_s))
        if result is None or result.linear or not applies_to(est.intersample):
            return est
        if circuit == "armature":
            return with_linearity(est, result)
        return not_described(est, field_note(result, window["vf"], period_s))

    def _armature_measured(self, circuit: str, est: CircuitEstimate) -> bool:
        """Whether the armature's voltage is read as measured (``smooth``): by this window, by
        the armature's first window (cold, its whole search range), or by as many of its
        windows before this one as read it held, described or not. A held reference (the
        ideal drive's voltage, constant over each sample) reads as held in nearly every
        window and from the first; an in-step chopper's steady stretches read as held too,
        and the field chopper's steady voltage nearly always does. (A majority of the
        described windows was asked before: the traction motor behind a 2.5 kHz chopper
        sampled in step at 5 kHz read its first window as measured, not described, then
        most as held, and published Ra 20-32 % and K 28 % low as ``ok``.)"""
        if "armature" not in self.circuits or not applies_to(est.intersample):
            return False
        if circuit == "armature" and est.intersample == "smooth":
            return True
        reads = self._armature_reads  # the windows before this one
        return self._armature_first == "smooth" or 0 < reads["hold"] <= reads["smooth"]

    def _untested_note(self, circuit: str, window: dict[str, np.ndarray], period_s: float) -> str:
        """Why ``circuit``'s window is held before the armature voltage's first linearity
        test ("" when it is not): the voltages it depends on show no mains ripple, so no
        bridge made them (:func:`~observer.estimation.linearity.made_by_a_bridge`)."""
        voltages = ("va",) if circuit == "armature" else ("va", "vf")
        if any(
            made_by_a_bridge(
                window[name], period_s, winding="armature" if name == "va" else "field"
            )
            for name in voltages
        ):
            return ""
        return (
            f"the {circuit} voltage is measured and shows no mains ripple (a chopper's or a "
            "DC source's): whether its samples read the voltage or a curve of it (a chopper's "
            "pulses sampled in step with the ADC) is tested over the first "
            f"{RETEST_SECONDS:.0f} s of the armature's; held until then"
        )

    def _skip(self, index: int, t0: int, t1: int, reason: str) -> WindowResult:
        key = reason.split(":")[0]
        self.counts[f"skipped:{key}"] += 1
        self.last_skip_reason = reason
        log.debug("window %d skipped: %s", index, reason)
        return WindowResult(index, t0, t1, None, skip_reason=reason)

    def _prepare_circuit(
        self, circuit: str, index: int, window: dict[str, np.ndarray], period_s: float
    ) -> _Prepared:
        """The estimator's arguments for ``circuit``, from its state before this window."""
        cfg = self.config
        k = cfg.decimate
        dt = period_s * k
        # Decimation: inputs (voltages, the EMF's if and omega) averaged over each new
        # period, outputs (the winding's current) sampled at its start.
        outputs = {"field": ("if",), "armature": ("ia",)}[circuit]
        s = {c: _decimated(window[c], k, sample=c in outputs) for c in CIRCUIT_CHANNELS[circuit]}
        if k > 1:
            # The mean over each new period is the voltage's exact mean over the interval that
            # starts at the current's sample: the 'averaged' model takes it at the interval's
            # end (the sample after), and reconstructs the voltage within from its neighbours.
            volt = "vf" if circuit == "field" else "va"
            s[volt] = np.concatenate([s[volt][:1], s[volt][:-1]])
        search = self._search[circuit]
        rng = np.random.default_rng([cfg.seed, index, _CIRCUIT_INDEX[circuit]])
        full: SearchRange
        if circuit == "field":
            full = field_search_range(s["vf"], s["if"], dt)
        else:
            full = armature_search_range(s["va"], s["ia"], s["if"], s["omega"], dt)
        x0 = None
        init = None
        names = CIRCUIT_NAMES[circuit]
        r_prev, l_prev = self.tracker.value(names["R"]), self.tracker.value(names["L"])
        if l_prev is None:
            l_prev = search.last_l
        warm = search.factor is not None and r_prev is not None and l_prev is not None
        if warm:
            assert search.factor is not None and r_prev is not None and l_prev is not None
            r_in = min(max(r_prev, full.resistance_ohm[0]), full.resistance_ohm[1])
            l_in = min(max(l_prev, full.inductance_h[0]), full.inductance_h[1])
            x0 = (r_in, l_in)
            init = full.around(r_in, l_in, search.factor)
        kwargs: dict[str, Any] = dict(
            search_range=full,
            n_particles=cfg.warm_particles if warm else cfg.cold_particles,
            max_iterations=cfg.warm_iterations if warm else cfg.cold_iterations,
            rng=rng,
            x0=x0,
            init_range=init,
            explore_fraction=cfg.explore_fraction if warm else 0.0,
        )
        if (
            warm
            and search.factor is not None
            and search.factor <= cfg.min_range_factor
            and len(search.rms_history) >= 3
        ):
            # Settled: polish from the tracked state; the swarm only if that fit degrades.
            kwargs["settled_rms"] = cfg.degrade_ratio * statistics.median(search.rms_history)
        self._collect_filter(circuit, index)
        kwargs.update(self._chain_kwargs(circuit, k))
        return _Prepared(circuit, s, dt, kwargs, warm, index)

    def _finish_circuit(self, prep: _Prepared, est: CircuitEstimate) -> None:
        """``prep.circuit``'s own state after its estimate: chain, warm start, search range."""
        circuit = prep.circuit
        search = self._search[circuit]
        self._learn_chain(circuit, est, prep)
        search.warm = prep.warm
        if math.isfinite(est.inductance_h) and est.inductance_h > 0:
            search.last_l = est.inductance_h
        self._update_search(circuit, search, est, prep.warm)

    def _submit_remote(self, prepared: dict[str, _Prepared | Exception]) -> str | None:
        """Send the armature's estimate to the worker when both circuits run and it is ready
        (starting it at the first such window); the circuit sent, or None."""
        arm = prepared.get("armature")
        if not self._parallel or not isinstance(arm, _Prepared):
            return None
        if not isinstance(prepared.get("field"), _Prepared):
            return None
        if self._worker is None:
            self.start_worker()
            return None
        if not self._worker.ready():
            if self._worker.closed:
                self._worker_failed()
            return None
        try:
            self._worker.submit(arm)
        except WorkerFailed:
            self._worker_failed()
            return None
        self.worker_windows += 1
        return arm.circuit

    def _remote_result(self, prep: _Prepared) -> CircuitEstimate:
        """The worker's estimate of ``prep``; estimated here if the worker failed."""
        assert self._worker is not None
        try:
            est: CircuitEstimate = self._worker.result()
        except WorkerFailed:
            self._worker_failed()
            return run_estimator(prep)
        return est

    def _chain_kwargs(self, circuit: str, decimate: int) -> dict[str, Any]:
        """The estimator's chain options for this circuit: configured, decided, or still open."""
        if decimate > 1:
            # Voltages averaged over each new period: their exact means, not held values
            # (a converter's ripple varies within the period; read as held, and so exact,
            # Ra's std covered it in 42 % of the windows at 10 kHz / 4).
            return {"intersample": "averaged"}
        out: dict[str, Any] = {"front_ends": winding_front_ends(self.chain, circuit)}
        state = self._chain_state[circuit]
        if self.chain.intersample != "auto":
            out["intersample"] = self.chain.intersample
        elif state.model is not None:
            out["intersample"] = state.model
            out["fit_shift"] = False
            out["shift"] = state.shift
            out["mismatch"] = state.mismatch
            if state.voltage_filter is not None and out["front_ends"] is None:
                out["voltage_alias"] = state.voltage_filter.alias
                if state.voltage_filter.alias is not None:
                    out["identified_filter"] = state.voltage_filter.best
        return out

    def _learn_chain(self, circuit: str, est: CircuitEstimate, prep: _Prepared) -> None:
        voltage = prep.signals["vf" if circuit == "field" else "va"]
        dt, index = prep.dt, prep.index
        state = self._chain_state[circuit]
        if self.chain.intersample != "auto" or self.config.decimate > 1:
            return
        if state.model is not None:
            self._identify_voltage_filter(circuit, state, voltage, dt, index)
            return
        if not est.describes_window:
            return
        state.record(est)
        if sum(state.votes.values()) >= self.config.chain_windows:
            state.decide(functools.partial(self._noise_share, prep, est))
            self._identify_voltage_filter(circuit, state, voltage, dt, index)
            corrected = applied_mismatch(state.mismatch)
            log.info(
                "%s measurement chain decided over %d windows: %s voltage, delay %.2f samples%s",
                circuit, sum(state.votes.values()), state.model, state.shift,
                f", untold channels corrected for {corrected:.2f} x the commonest mismatch "
                "(an RC beside a 2nd-order filter)" if corrected else "",
            )  # fmt: skip

    def _noise_share(self, prep: _Prepared, est: CircuitEstimate) -> float:
        """What the voltage's noise adds to the mismatch of the channels this window measured:
        the window estimated again with as much white noise more on its voltage as it read
        (the same swarm draws), the growth of the size (0: not measurable, or none)."""
        if not (est.input_noise_var > 0.0 and math.isfinite(est.mismatch_size)):
            return 0.0
        volt = "vf" if prep.circuit == "field" else "va"
        signals = dict(prep.signals)
        signals[volt] = signals[volt] + simex_noise(signals[volt].shape[0], est.input_noise_var)
        rng = np.random.default_rng([self.config.seed, prep.index, _CIRCUIT_INDEX[prep.circuit]])
        noisier = run_estimator(
            dataclasses.replace(prep, signals=signals, kwargs={**prep.kwargs, "rng": rng})
        )
        grown = noisier.mismatch_size - est.mismatch_size
        # Noise only ever adds to it (it reads as a low-pass of the voltage); a window's
        # size that fell is that window's own scatter, not the noise's share.
        return max(float(grown), 0.0) if math.isfinite(grown) else 0.0

    def _identify_voltage_filter(
        self, circuit: str, state: _ChainState, voltage: np.ndarray, dt: float, index: int
    ) -> None:
        """Untold front ends and a filtered voltage: which filter, from the converter's
        jumps in window ``index`` (:mod:`observer.estimation.filter_id`), identified in a
        thread and used from a fixed window on (:data:`FILTER_DUE_S`). A window with too few
        jumps (a drive at standstill) is followed by another try every ``chain_windows``
        windows, at most :data:`FILTER_TRIES` times; a voltage the jumps' model does not
        describe is not tried again."""
        if state.model != "smooth" or winding_front_ends(self.chain, circuit) is not None:
            return
        if circuit not in IDENTIFIED_WINDINGS or state.pending is not None:
            return
        fit = state.voltage_filter
        if fit is not None and (fit.alias is not None or not fit.too_few_jumps):
            return
        state.filter_windows += 1
        if (state.filter_windows - 1) % self.config.chain_windows:
            return
        if state.filter_tries(self.config.chain_windows) > FILTER_TRIES:
            return
        if self._identifier is None:
            self._identifier = ThreadPoolExecutor(1, thread_name_prefix="dcobserver-filter")
        job = self._identifier.submit(identify_voltage_filter, np.array(voltage), dt)
        state.pending = (job, index + self._filter_due)

    def _collect_filter(self, circuit: str, index: int) -> None:
        """From its window on, the identified voltage filter of ``circuit`` (waiting for it)."""
        state = self._chain_state[circuit]
        if state.pending is None or index < state.pending[1]:
            return
        job, _ = state.pending
        state.pending = None
        fit = state.voltage_filter = job.result()
        tries = state.filter_tries(self.config.chain_windows)
        if fit.alias is not None:
            log.info(
                "%s voltage filter identified from %d jumps: %s (residual %.3g V), aliasing "
                "factor %.4f", circuit, fit.jumps, fit.text, fit.rms_v, fit.alias,
            )  # fmt: skip
        elif not fit.too_few_jumps or tries == FILTER_TRIES:
            log.info(
                "%s voltage filter not identified (%s): the weakest filter in use is assumed "
                "(configure [chain])", circuit, fit.reason,
            )  # fmt: skip

    def _update_search(
        self, circuit: str, search: _Search, est: CircuitEstimate, warm: bool
    ) -> None:
        """The next window's warm start: shrink while fits agree with the tracked state."""
        cfg = self.config
        agree = {"R": cfg.agree.R, "L": cfg.agree.L, "K": cfg.agree.K}
        raw = {"R": est.resistance_ohm, "L": est.inductance_h, "K": est.emf_constant_h}
        limits = cfg.quality.limits(circuit)
        jumped = False
        for p, name in CIRCUIT_NAMES[circuit].items():
            tracked, value = self.tracker.value(name), raw[p]
            if tracked is None or value is None or not est.relative_std(p) <= limits[p]:
                continue
            jumped |= abs(value / tracked - 1.0) > agree[p]
        history = list(search.rms_history)
        degraded = len(history) >= 3 and est.rms_a > cfg.degrade_ratio * statistics.median(history)
        search.rms_history.append(est.rms_a)
        names = CIRCUIT_NAMES[circuit]
        known = all(self.tracker.value(names[p]) is not None for p in ("R", "L"))
        if jumped or degraded:
            # Widen; after a large jump search from scratch over the full range.
            self.counts[f"{circuit}_widened"] += 1
            base = search.factor if search.factor is not None else cfg.initial_range_factor
            widened = 1.0 + (base - 1.0) * cfg.widen
            search.factor = None if widened >= cfg.max_range_factor else widened
        elif known or est.relative_std("R") <= limits["R"]:
            if search.factor is None:
                search.factor = cfg.initial_range_factor
            elif warm:
                search.factor = max(cfg.min_range_factor, 1.0 + (search.factor - 1.0) * cfg.shrink)

    # ------------------------------------------------------------------ tracked state

    def _evidence(self, fits: dict[str, CircuitEstimate | None]) -> dict[str, Evidence | None]:
        """Each parameter's fit in this window, or None where the window is no evidence."""
        evidence: dict[str, Evidence | None] = {}
        for name in PARAMETERS:
            circuit, p = LOCATION[name]
            est = fits.get(circuit)
            if est is None or not est.describes_window:
                evidence[name] = None
                continue
            value = est.value(p)
            rel = est.relative_std(p)
            ok = value is not None and math.isfinite(value) and math.isfinite(rel)
            shared = est.relative_shared_std(p)
            evidence[name] = Evidence(float(value), float(rel), shared) if ok else None  # type: ignore[arg-type]
        return evidence

    def _copper_loss(
        self,
        signals: dict[str, np.ndarray],
        period_s: float,
        fits: dict[str, CircuitEstimate | None],
    ) -> float | None:
        """The machine's I^2R loss (W) over the last hop, from the tracked resistances
        (before the first evidence: from this window's fits)."""
        n = max(1, int(round(self.config.hop_s / period_s)))
        loss = 0.0
        known = False
        for name, channel in (("Rf", "if"), ("Ra", "ia")):
            r = self.tracker.value(name)
            fit = fits.get(LOCATION[name][0])
            if r is None and fit is not None and math.isfinite(fit.resistance_ohm):
                r = fit.resistance_ohm
            current = signals[channel][-n:]
            if r is None or np.isnan(current[0]):
                continue
            loss += r * float(np.mean(current * current))
            known = True
        return loss if known else None

    def _circuit_output(
        self, circuit: str, est: CircuitEstimate | None, step: TrackerStep
    ) -> dict[str, Any]:
        """The circuit's part of the estimate message: tracked state beside the window's fit."""
        names = CIRCUIT_NAMES[circuit]
        tracked = {p: step.parameters[name] for p, name in names.items()}
        out: dict[str, Any] = {p: _finite_or_none(t.value) for p, t in tracked.items()}
        out["std"] = {p: _finite_or_none(t.std) for p, t in tracked.items()}
        out["quality"] = {p: t.status for p, t in tracked.items()}
        out["rate_per_min"] = {"R": _finite_or_none(tracked["R"].rate_per_min)}
        out["std_scale"] = {p: _finite_or_none(t.std_scale) for p, t in tracked.items()}
        if est is None:
            out["raw"] = {p: None for p in names}
            out["rel_std"] = {p: None for p in names}
            return out
        raw = {"R": est.resistance_ohm, "L": est.inductance_h, "K": est.emf_constant_h}
        out["raw"] = {p: _finite_or_none(raw[p]) for p in names}
        out["rel_std"] = {p: _finite_or_none(est.relative_std(p)) for p in names}
        out["shared_rel_std"] = {p: _finite_or_none(est.relative_shared_std(p)) for p in names}
        out["rms"] = _finite_or_none(est.rms_a)
        out["describes_window"] = est.describes_window
        if est.note:
            out["note"] = est.note
        search = self._search[circuit]
        out["warm"] = search.warm
        out["range_factor"] = search.factor
        out["evaluations"] = est.pso.n_evaluations
        if circuit == "armature":
            out["input_noise_var"] = est.input_noise_var
        out["chain"] = {
            "intersample": est.intersample,
            "shift_samples": est.shift_samples,
            "front_end_std_L": est.front_end_std,
            # Untold channels: the size of the commonest mismatch this window measured, and
            # the one the decided chain corrects every window for (0: none).
            "mismatch_measured": _finite_or_none(est.mismatch_size),
            "mismatch_corrected": applied_mismatch(self._chain_state[circuit].mismatch),
            "decided": self._chain_state[circuit].model is not None,
            # Untold front ends: the voltage filter identified from the converter's jumps
            # that this window's std and reconstruction used (None: none yet, or none found).
            "identified_filter": _identified(self._chain_state[circuit].voltage_filter),
        }
        if circuit == "field" and tracked["L"].status == "ok":
            self._check_field_window(tracked["L"].value, tracked["R"].value)
        if est is not None:
            self._check_front_ends(circuit, est)
            self._check_described(circuit, est)
        return out

    def _check_described(self, circuit: str, est: CircuitEstimate) -> None:
        """Say once per circuit why its windows are held when the model cannot describe them."""
        key = f"not_described_{circuit}"
        if est.describes_window or key in self.warnings:
            return
        self.warnings.add(key)
        log.warning(
            "%s held: the model does not describe this window (%s)",
            circuit, est.note or "no reason given",
        )  # fmt: skip

    def _check_front_ends(self, circuit: str, est: CircuitEstimate) -> None:
        """Say once why L is held where the channels' unknown front ends alone hold it."""
        key = f"front_ends_{circuit}"
        share = est.front_end_std / est.inductance_h if est.inductance_h > 0 else 0.0
        limit = self.config.quality.limits(circuit)["L"]
        if key in self.warnings or not share > limit:
            return
        self.warnings.add(key)
        name = CIRCUIT_NAMES[circuit]["L"]
        log.warning(
            "%s held: the %s voltage and current front ends are not configured, and this "
            "window leaves room for channels filtered differently that would move %s by "
            "%.1f %% (quality limit %.1f %%); configure [chain] (docs/drive_chain.md)",
            name, circuit, name, 100 * share, 100 * limit,
        )  # fmt: skip

    def _check_field_window(self, inductance: float | None, resistance: float | None) -> None:
        cfg = self.config
        if inductance is None or resistance is None:
            return
        tau = inductance / resistance
        if cfg.window_s < cfg.min_field_taus * tau:
            if "window_short_for_field" not in self.warnings:
                log.warning(
                    "window_s = %g s is shorter than %g field time constants (%.3g s each): "
                    "raise observer.window_s",
                    cfg.window_s, cfg.min_field_taus, tau,
                )  # fmt: skip
            self.warnings.add("window_short_for_field")

    def _temperatures(self, step: TrackerStep) -> dict[str, tuple[float, float]]:
        """Winding temperatures and their one-sigma (deg C, K) from the tracked resistances,
        where a reference is set."""
        cfg = self.config.tracker
        out: dict[str, tuple[float, float]] = {}
        for circuit, name, r_ref in (
            ("field", "Rf", cfg.field_r_ref_ohm), ("armature", "Ra", cfg.armature_r_ref_ohm),
        ):  # fmt: skip
            tracked = step.parameters[name]
            if r_ref <= 0 or tracked.value is None or tracked.std is None:
                continue
            temp, std = winding_temperature(
                tracked.value, tracked.std / tracked.value, r_ref, cfg.alpha_per_k, cfg.reference_c
            )
            out[circuit] = (temp, std)
        return out

    def _speed_parameters(
        self, fit: CircuitEstimate | None = None
    ) -> tuple[dict[str, tuple[float, float]] | None, str]:
        """``Ra, La, K`` (value, relative std) for the EMF speed, and where they come from.

        ``La`` only weighs the current's change over the window (``La * dia/dt``
        averages to ``La * (ia_end - ia_start) / window``), and some drives run
        for long without a window that identifies it: until it is tracked, the
        window's own fit ``fit`` stands in with its std (at most 100 %), so the
        tachometer is checked from the first windows that know ``Ra`` and ``K``.
        """
        tracked = {n: (self.tracker.value(n), self.tracker.rel_std(n)) for n in ("Ra", "La", "K")}
        la_fit = None if fit is None else fit.inductance_h
        if tracked["La"][0] is None and la_fit is not None and math.isfinite(la_fit) and la_fit > 0:
            assert fit is not None
            la_rel = fit.relative_std("L")
            tracked["La"] = (la_fit, min(la_rel, 1.0) if math.isfinite(la_rel) else 1.0)
        if all(v is not None and s is not None for v, s in tracked.values()):
            return {n: (float(v), float(s)) for n, (v, s) in tracked.items()}, "tracked"  # type: ignore[arg-type]
        cfg = self.config.speed
        if cfg.K_h > 0:
            return {"Ra": (cfg.Ra_ohm, 0.0), "La": (cfg.La_h, 0.0), "K": (cfg.K_h, 0.0)}, (
                "configured [observer.speed] Ra_ohm, La_h, K_h"
            )
        return None, ""

    def _emf_speed(
        self, signals: dict[str, np.ndarray], period_s: float, fit: CircuitEstimate | None
    ) -> SpeedEstimate | None:
        if any(np.isnan(signals[c][0]) for c in ("va", "ia", "if")):
            return None
        params, _source = self._speed_parameters(fit)
        if params is None:
            return None
        omega = None if np.isnan(signals["omega"][0]) else signals["omega"]
        return emf_speed(signals["va"], signals["ia"], signals["if"], omega, period_s, params)

    def _speed_output(
        self, speed: SpeedEstimate | None, signals: dict[str, np.ndarray]
    ) -> dict[str, Any]:
        out: dict[str, Any] = {
            "emf_rad_s": None if speed is None else _finite_or_none(speed.emf_rad_s),
            "std_rad_s": None if speed is None else _finite_or_none(speed.std_rad_s),
            "measured_rad_s": None if speed is None else _finite_or_none(speed.measured_rad_s),
            "measured_std_rad_s": None if speed is None else speed.measured_std_rad_s,
            "tachometer": "fault" if self.tachometer.faulty else "ok",
        }
        if np.isnan(signals["omega"][0]):
            _, source = self._speed_parameters()
            out["tachometer"] = "none"
            out["note"] = (
                "no speed channel: the armature equation holds only K*omega, so K and the "
                "speed cannot be separated, and Ra, La, K are not estimated; "
                + (f"the EMF speed uses the {source} values" if source else
                   "set [observer.speed] K_h (and Ra_ohm, La_h) for an EMF speed")
            )  # fmt: skip
        return out

    @staticmethod
    def _change_event(change: Any) -> dict[str, Any]:
        circuit, p = LOCATION[change.parameter]
        units = {"R": "ohm", "L": "H", "K": "H"}[p]
        verb = "rose" if change.relative > 0 else "fell"
        cause = {
            ("Ra", 1): " (a loose connection or brushes?)",
            ("K", -1): " (a field fault?)",
        }.get((change.parameter, 1 if change.relative > 0 else -1), "")
        return {
            "kind": "change",
            "parameter": change.parameter,
            "circuit": circuit,
            "t_ns": int(change.t_detected_ns),
            "t_change_ns": int(change.t_change_ns),
            "relative": change.relative,
            "relative_std": change.relative_std,
            "before": change.before,
            "after": change.after,
            "message": (
                f"{change.parameter} {verb} {100 * abs(change.relative):.1f} % "
                f"({change.before:.4g} -> {change.after:.4g} {units}) at about "
                f"{change.t_change_ns / 1e9:.2f} s{cause}"
            ),
        }

    def health(self) -> dict[str, Any]:
        """Counters for the health topic."""
        return {
            "windows": dict(self.counts),
            "next_index": self.next_index,
            "last_skip_reason": self.last_skip_reason,
            "warnings": sorted(self.warnings),
            "range_factor": {c: t.factor for c, t in self._search.items()},
            "chain": {c: st.to_dict() for c, st in self._chain_state.items()},
            # The armature voltage reading's linearity test, last result (None: not yet).
            "voltage_linearity": (
                self.voltage_linearity.to_dict() if self.voltage_linearity is not None else None
            ),
            "tracker": dict(self.tracker.counts),
            # The armature's estimates in a second process: off, starting, on, failed.
            "parallel": {
                "state": self.parallel_state,
                "windows": self.worker_windows,
                "failures": self.worker_failures,
            },
            "tachometer": {
                "state": "fault" if self.tachometer.faulty else "ok",
                **self.tachometer.counts,
            },
        }


def warm_up_kernels() -> float:
    """Compile (or load from the numba cache) every kernel the observer uses; seconds taken.

    On a cold cache (a fresh clone) a kernel compiles at its first call with a
    new signature, which takes seconds: a window that waited for that would
    make live mode skip windows. So the estimators run here once on a small
    synthetic window, with the very argument types the observer passes
    (writable contiguous float64 arrays, as the ring buffer hands out: numba
    compiles read-only ones separately, see
    :func:`observer.estimation.ranges.kernel_array`). The window is made by the
    estimator's own winding models, so the service needs no simulator.
    """
    from observer.estimation import filter_id, kernels
    from observer.estimation.motor import P12

    started = time.monotonic()
    filter_id.warm_up()
    dt = 1e-3
    va, ia, vf, i_f, omega = _synthetic_windings(P12, n=200, dt=dt)
    # The bridge check's and the linearity test's scipy.signal: ~0.6 s to import, which the
    # first untested window (or the test's thread, holding the GIL) would otherwise wait for.
    made_by_a_bridge(va, dt, winding="armature")
    # The compensated swarm's call, whatever the fits below reach.
    emf = kernels.emf_input(i_f, omega)
    x = np.log10([[3.5, 0.02]])
    kernels.armature_swarm_costs(x, va, emf, ia, dt, True, float("nan"), 0.5)
    kernels.rl_swarm_costs(x, vf, i_f, dt, True, 0.5)
    # Only compilation matters here: a fit of 0.2 s may fail, the kernels are loaded anyway.
    try:
        estimate_field(vf, i_f, dt, n_particles=4, max_iterations=2, rng=0)
    except (ArithmeticError, ValueError):
        pass
    try:
        estimate_armature(va, ia, i_f, omega, dt, n_particles=4, max_iterations=2, rng=0)
    except (ArithmeticError, ValueError):
        pass
    return time.monotonic() - started


def _synthetic_windings(
    motor: MotorParameters, *, n: int, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``va, ia, vf, if, omega`` of a drive accelerating under stepped voltages, 0.2 % noise.

    The currents are the exact discrete winding models
    (:func:`~observer.estimation.kernels.simulate_rl`,
    :func:`~observer.estimation.kernels.simulate_armature`) of ``motor``, not a
    simulated drive: enough for every kernel to be called as in a real window.
    """
    from observer.estimation import kernels

    rng = np.random.default_rng(0)
    steps = np.where((np.arange(n) // 50) % 2 == 0, 1.0, 0.75)
    vf = float(motor.rated_field_voltage_v) * steps
    i_f0 = float(motor.rated_field_current_a)
    i_f = kernels.simulate_rl(
        float(motor.field_resistance_ohm), float(motor.field_inductance_h), i_f0, vf, dt
    )
    omega = float(motor.rated_speed_rad_s) * np.linspace(0.2, 0.6, n)
    va = float(motor.rated_armature_voltage_v) * (0.5 + 0.25 * steps)
    ia = kernels.simulate_armature(
        float(motor.armature_resistance_ohm), float(motor.armature_inductance_h),
        float(motor.emf_constant_h), 0.0, va, kernels.emf_input(i_f, omega), dt,
    )  # fmt: skip
    rated = (
        motor.rated_armature_voltage_v, motor.rated_armature_current_a,
        motor.rated_field_voltage_v, motor.rated_field_current_a, motor.rated_speed_rad_s,
    )  # fmt: skip
    signals = (va, ia, vf, i_f, omega)
    va, ia, vf, i_f, omega = (
        s + 0.002 * float(r) * rng.standard_normal(n) for s, r in zip(signals, rated, strict=True)
    )
    return va, ia, vf, i_f, omega


def _kphi(armature: dict[str, Any], field_current: np.ndarray) -> dict[str, float | None]:
    """kPhi of the tracked K at the window's mean field current
    (:func:`observer.estimation.result.kphi`), with that current."""
    k, k_std = armature.get("K"), armature.get("std", {}).get("K")
    i_f = float(np.nanmean(field_current)) if field_current.size else math.nan
    if k is None or not math.isfinite(i_f):
        return {"kphi": None, "kphi_std": None, "if_mean": _finite_or_none(i_f)}
    value, std = kphi(k, math.nan if k_std is None else k_std, i_f)
    return {"kphi": _finite_or_none(value), "kphi_std": _finite_or_none(std), "if_mean": i_f}
