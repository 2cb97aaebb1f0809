"""What the winding voltage did between samples: the intersample model of a window.

Output error simulates the winding current from the measured voltage, so it
needs the voltage *between* the samples. Three models, one per kind of drive
and measurement chain (chosen per window by :func:`choose_model`, or set in
config):

``hold``
    The voltage is constant over each sample period: a digital drive that
    reports the voltage it holds for the period (its modulator reference).
    This is the model of the paper and of dcobserver before converter-fed
    drives; :mod:`observer.estimation.kernels` discretises it exactly.
``smooth``
    The voltage was measured through an anti-aliasing filter, so it is
    band-limited: between the samples it is the band-limited (Whittaker-
    Shannon) interpolant of the samples (:func:`smooth_moments`; a cubic on
    segments too short for a spectrum). A cubic is not enough there: a
    converter's ripple sits at a few samples per period, where a cubic's
    interval means err by percents, and the inductance, which the ripple
    current identifies, errs with them (-1.2 % at 2 kHz on a 6-pulse bridge
    behind a 2nd-order filter at fs/4; +0.2 % band-limited). A relative delay
    between the voltage and current channels (filters of different group
    delay, a multiplexed ADC) is a parameter of the fit.
``averaged``
    An integrating measurement: each sample is the voltage's mean over the
    period that ends at it, whatever the converter did inside it. The
    moments of the period between two current samples are then known
    exactly (the mean) or nearly (its slope and curvature, from the
    neighbouring means).
``switched``
    The voltage was sampled without (enough) filtering from a switching
    converter: mains sine segments with a jump at every thyristor firing or
    current extinction. Between jumps the voltage is smooth and the cubic
    holds; an interval that contains a jump is not known (the samples do not
    say when it happened), so the output-error simulation restarts after it
    (see the segments of :mod:`observer.estimation.intersample_kernels`).

Each model is turned into Legendre moments of the voltage over every interval,
the input :func:`~observer.estimation.intersample_kernels.moment_swarm_costs`
takes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from observer.estimation import intersample_kernels as ik

MODELS = ("hold", "smooth", "switched", "averaged")

#: Mains frequencies a line-commutated converter's segments and ripple are locked to (Hz).
MAINS_HZ = (50.0, 60.0)

#: A jump must exceed this many robust standard deviations of the smooth parts'
#: extrapolation error on both sides of its interval.
JUMP_SIGMAS = 8.0

#: Segments shorter than this many samples are dropped (too short to carry a
#: current's evolution beyond its own initial value).
MIN_SEGMENT = 3

#: Below this share of intervals with a clean jump, a channel is not switched.
MIN_SWITCHED_SHARE = 0.005

#: A clean jump flags a run of at most this many intervals (the sine's one-sided test flags
#: the two before the sample it misses). Behind a filter a jump flags three or four, and on a
#: bridge locked to the samples (50 Hz mains at 2 kHz) one of them passed every test of a
#: clean jump in every pulse: a 2nd-order Butterworth at fs/4 read ``switched`` for a quarter
#: second of the field's start, a 4th-order Bessel at fs/5 on a 3-phase field bridge in two
#: windows of three; the field's resistance was then 1.5-3 % off at 5 of its std.
MAX_CLEAN_RUN = 2

#: A run of flagged intervals longer than :data:`MAX_CLEAN_RUN` is two clean jumps when the
#: samples between its ends bend by at most this many robust standard deviations (second
#: differences): between the jumps of discontinuous conduction, unfiltered, 0-2.1 at 5 and
#: 10 kHz (0-5 at 2 kHz, where the back-EMF's few samples span 1.5 ms); the settling samples
#: of a 4th-order Bessel at fs/5, 2.8-4.5.
STRAIGHT_SIGMAS = 2.5

#: ... and by at most this share of the smaller of its two end jumps (behind a filter the
#: robust scale is the filter's misfit of the sine arcs, up to 12 V on a 300 V bridge at
#: 2 kHz, and a settling sample passes the test above; it bends by tens of percent of the
#: jump, the back-EMF between two clean jumps by a few).
STRAIGHT_SHARE = 0.1

#: A filtered jump settles over at most this many intervals after its flagged ones.
MAX_SETTLING = 4

#: A sample has settled when the quadratic from the three after it predicts it
#: within this many robust standard deviations.
SETTLED_SIGMAS = 3.0

#: A jump the mains sine sees from one side only is clean when its neighbours' misses
#: are also below this share of that miss. Behind a filter the sine's scale is the
#: filter's misfit, not the noise, and settling samples pass the noise test: at 2 kHz
#: behind a 2nd-order filter at fs/4 the neighbours carry 4-35 % (10-90 %) of the miss
#: and a window in ten read ``switched``; unfiltered 0.7-4 % (0.2 % noise), 4-25 % (2 %).
ALONE_CLEAN_SHARE = 0.1


@dataclass(frozen=True)
class Segments:
    """Sample ranges ``[starts[i], ends[i]]`` (inclusive) over which the voltage is known.

    Attributes
    ----------
    starts, ends : (n_segments,) int64 arrays
    n_samples : int
        Samples of the window (segments cover a subset).
    """

    starts: np.ndarray
    ends: np.ndarray
    n_samples: int

    @classmethod
    def whole(cls, n: int) -> Segments:
        return cls(np.array([0], dtype=np.int64), np.array([n - 1], dtype=np.int64), n)

    @property
    def count(self) -> int:
        return int(self.starts.shape[0])

    @functools.cached_property
    def covered(self) -> int:
        """Samples inside segments (asked for at every residual the polish takes)."""
        return int(np.sum(self.ends - self.starts + 1))

    def mask(self) -> np.ndarray:
        """Boolean per sample: inside a segment."""
        out = np.zeros(self.n_samples, dtype=bool)
        for s, e in zip(self.starts, self.ends, strict=True):
            out[s : e + 1] = True
        return out


@dataclass(frozen=True)
class Switching:
    """Where a sampled voltage jumps between samples.

    Attributes
    ----------
    jumps : (n - 1,) bool array
        Per interval: a jump falls inside it.
    clean_share : float
        Share of intervals holding a *clean* jump, one that flags its interval
        alone (none within two intervals), as an unfiltered converter voltage
        does (a filtered voltage settles over several samples and flags a run
        of intervals, or rings); 0 when
        most flagged intervals are in runs.
    noise_v : float
        Robust standard deviation of the smooth parts' one-sided quadratic
        extrapolation error (V): noise plus curvature.
    transitions : (n - 1,) bool array
        ``jumps`` widened forward over the intervals whose later sample is
        still settling (a filtered jump), up to :data:`MAX_SETTLING` intervals.
    """

    jumps: np.ndarray
    clean_share: float
    noise_v: float
    transitions: np.ndarray | None = None

    @property
    def switched(self) -> bool:
        return self.clean_share >= MIN_SWITCHED_SHARE

    @property
    def transition_mask(self) -> np.ndarray:
        """Per interval: inside a transition (``transitions``, else the ``jumps`` alone)."""
        return self.transitions if self.transitions is not None else self.jumps

    @property
    def transition_share(self) -> float:
        """Share of intervals inside a transition (a jump and the samples still settling)."""
        t = self.transition_mask
        return float(np.count_nonzero(t)) / max(t.shape[0], 1)

    def widened(self, m: int) -> Switching:
        """These transitions, each widened forward by ``m`` intervals (the samples still
        settling after them)."""
        if m <= 0:
            return self
        t = self.transition_mask
        out = t.copy()
        for k in range(1, m + 1):
            out[k:] |= t[:-k]
        return Switching(self.jumps, self.clean_share, self.noise_v, out)


def _robust_std(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _smooth_scale(miss_left: np.ndarray, miss_right: np.ndarray) -> float:
    """Robust standard deviation of one-sided extrapolation misses on smooth stretches.

    Jumps every few samples (a 6-pulse bridge at 2 kHz: one every ~7) spoil
    most three-sample stencils on one side, but a sample rarely has jumps on
    both: the smaller of its two misses is clean. The median of the smaller of
    two independent half-normal magnitudes is 0.375 sigma.
    """
    both = np.fmin(np.abs(miss_left), np.abs(miss_right))
    both = both[np.isfinite(both)]
    if both.size == 0:
        return 0.0
    return float(np.median(both)) / 0.375


def _predictors(v: np.ndarray, dt: float | None) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """One-sided extrapolation misses of each sample, from the left and from the right.

    Two predictors of a smooth voltage, each with the scale of its misses on
    smooth stretches (:func:`_smooth_scale`): the quadratic through the three
    samples on one side (any slowly varying voltage: a chopper's DC link, a
    filtered converter, a back-EMF), and, when the sample period ``dt`` is
    known, the recurrence ``v[k+1] = 2 cos(w dt) v[k] - v[k-1]`` that every
    sine of frequency ``w`` obeys exactly: a line-commutated bridge's voltage
    between its commutations is a segment of the mains' sine (of
    :data:`MAINS_HZ`, the one it fits better). Near the crest of a 6-pulse
    bridge's output sampled at 2 kHz (6.7 samples per pulse) the quadratic
    misses smooth samples by up to a fifth of a firing's jump, and
    extrapolated across a jump its curvature can take up most of it (a 56 V
    firing missed by 15 V from one side, under its threshold); the sine misses
    them by the noise alone. The sine misses a back-EMF (discontinuous
    conduction) by ``E (w dt)**2``, the quadratic does not.
    """
    n = v.shape[0]
    # left[k] predicts v[k] from v[k-3], v[k-2], v[k-1]; right[k] from v[k+1..k+3].
    left = np.full(n, np.nan)
    left[3:] = 3.0 * v[2:-1] - 3.0 * v[1:-2] + v[:-3]
    right = np.full(n, np.nan)
    right[:-3] = 3.0 * v[1:-2] - 3.0 * v[2:-1] + v[3:]
    out = [(v - left, v - right, _smooth_scale(v - left, v - right))]
    if dt is not None and dt > 0:
        sines = []
        for mains in MAINS_HZ:
            c2 = 2.0 * math.cos(2.0 * math.pi * mains * dt)
            left = np.full(n, np.nan)
            left[2:] = c2 * v[1:-1] - v[:-2]
            right = np.full(n, np.nan)
            right[:-2] = c2 * v[1:-1] - v[2:]
            sines.append((v - left, v - right, _smooth_scale(v - left, v - right)))
        out.append(min(sines, key=lambda m: m[2]))
    return out


def _clean_in_runs(clean: np.ndarray, jumps: np.ndarray, v: np.ndarray, scale: float) -> np.ndarray:
    """``clean`` without the intervals of runs of flagged ones that a filtered jump made.

    A clean jump flags its own interval, or two where the sine cannot tell which of them
    holds it (:data:`MAX_CLEAN_RUN`). A longer run is either a filtered jump still settling,
    one of whose intervals can pass every test of a clean one, or two clean jumps with a
    short segment between them (the current dying out and the next firing, in discontinuous
    conduction): then both its end intervals are clean and the samples between them lie on
    a smooth curve (:data:`STRAIGHT_SIGMAS`).
    """
    edges = np.flatnonzero(np.diff(np.concatenate([[0], jumps.astype(np.int8), [0]])))
    starts, stops = edges[::2], edges[1::2]
    out = clean.copy()
    for start, stop in zip(
        starts[stops - starts > MAX_CLEAN_RUN], stops[stops - starts > MAX_CLEAN_RUN], strict=True
    ):
        inner = v[start + 1 : stop]  # the samples between the run's first and last interval
        jumps_v = min(abs(float(v[start + 1] - v[start])), abs(float(v[stop] - v[stop - 1])))
        bend = float(np.max(np.abs(np.diff(inner, 2)))) if inner.shape[0] >= 3 else 0.0
        straight = bend <= STRAIGHT_SIGMAS * scale and bend <= STRAIGHT_SHARE * jumps_v
        if not (clean[start] and clean[stop - 1] and straight):
            out[start:stop] = False
    return out


def find_switching(v: np.ndarray, dt: float | None = None) -> Switching:
    """Locate the intervals of ``v`` that contain a jump (see :class:`Switching`).

    A smooth predictor from the samples on one side of an interval predicts the
    sample on the other side; a jump makes both one-sided predictions across
    its interval miss by far more than the smooth parts ever do. Each of
    :func:`_predictors` (``dt``, the sample period, adds the mains sine's) is
    judged against its own scale, and an interval either flags holds a jump:
    each sees jumps the other's curvature hides.
    """
    n = v.shape[0]
    jumps = np.zeros(max(n - 1, 0), dtype=bool)
    if n < 8:
        return Switching(jumps, 0.0, 0.0)
    clean = np.zeros_like(jumps)
    settled = np.zeros(n, dtype=bool)
    scales = []
    for sine, (miss_left, miss_right, scale) in enumerate(_predictors(v, dt)):
        if not scale > 0:
            scale = _robust_std(np.diff(v)) or 1e-12
        scales.append(scale)
        threshold = JUMP_SIGMAS * scale
        across_left = np.abs(miss_left[1:]) > threshold  # interval k: v[k+1] missed from the left
        across_right = np.abs(miss_right[:-1]) > threshold  # interval k: v[k] missed from the right
        flags = across_left & across_right
        alone_miss = np.zeros_like(flags, dtype=float)
        if sine:
            # The sine's miss of v[j] from v[j-2], v[j-1] is its miss of v[j-2] from the right:
            # a jump in interval j-2 or j-1 shows in it. Fired just after the crossing of
            # the two line voltages (a small firing angle), the old and the new sine
            # still agree at the sample before the jump: one of the two misses across it
            # stays small, and the jump is in one of the two intervals of the other.
            big = np.abs(np.nan_to_num(miss_left, nan=0.0)) > threshold
            alone = big.copy()
            alone[1:] &= ~big[:-1]
            alone[:-1] &= ~big[1:]
            at = np.flatnonzero(alone)
            for back in (2, 1):
                before = at[at >= back] - back
                alone_miss[before] = np.where(flags[before], 0.0, np.abs(miss_left[before + back]))
                flags[before] = True
        # Intervals at the window's edges cannot be judged from both sides.
        flags[:3] = False
        flags[-3:] = False
        # A clean jump leaves both its samples on their own smooth curves: the one
        # before it is predicted from the left, the one after it from the right. A
        # filtered jump settles over several samples (or rings), so its
        # neighbours are still in transition.
        on_left = np.abs(np.nan_to_num(miss_left[:-1], nan=np.inf)) <= SETTLED_SIGMAS * scale
        on_right = np.abs(np.nan_to_num(miss_right[1:], nan=np.inf)) <= SETTLED_SIGMAS * scale
        # A jump seen from one side only must also stand out against its neighbours'
        # misses: behind a filter the scale is loose (see :data:`ALONE_CLEAN_SHARE`).
        neighbours = np.fmax(
            np.abs(np.nan_to_num(miss_left[:-1], nan=np.inf)),
            np.abs(np.nan_to_num(miss_right[1:], nan=np.inf)),
        )
        stands_out = (alone_miss == 0.0) | (neighbours <= ALONE_CLEAN_SHARE * alone_miss)
        jumps |= flags
        clean |= flags & on_left & on_right & stands_out
        settled |= np.abs(miss_right) <= SETTLED_SIGMAS * scale
    clean = _clean_in_runs(clean, jumps, v, min(scales))
    flagged = int(np.count_nonzero(jumps))
    share = float(np.count_nonzero(clean)) / max(n - 1, 1)
    if flagged and np.count_nonzero(clean) < 0.25 * flagged:
        share = 0.0
    # A filtered jump is still settling after its flagged intervals: widen each
    # run forward until the next sample lies on the smooth curve after it.
    transitions = jumps.copy()
    ends = np.flatnonzero(jumps & ~np.concatenate([jumps[1:], [False]]))
    # (All runs at once, a step of the settling at a time.)
    going = np.ones(ends.shape[0], dtype=bool)
    for step in range(1, MAX_SETTLING + 1):
        j = ends + step
        going &= j < n - 1
        going[going] &= ~settled[j[going]]
        transitions[j[going]] = True
    return Switching(jumps, share, min(scales), transitions)


#: A current's bend after a voltage jump is followed over at most this many samples (a
#: 2nd-order filter at fs/8 decays by e**-4 over about 7).
MAX_CURRENT_SETTLING = 8

#: The current's mean bend after a jump must stand this many standard errors out, and be
#: at least :data:`BEND_SHOWS` of the bend across the jump itself, to show a filter on the
#: current's channel that the voltage's does not share (unfiltered: below 1 %; behind a
#: 2nd-order filter at fs/4: 85 %). At 10 standard errors one 1 s window in ten of a 60 mH
#: armature at 5 kHz missed its filter (its bends are a third of the P-12's) and read La
#: -1.4 % at 7 std; the share test keeps unfiltered currents out at 5.
BEND_SIGMAS = 5.0
BEND_SHOWS = 0.05

#: The bend has died out once it is below this share of the bend across the jump (and
#: within three standard errors of zero).
BEND_SETTLED = 0.01


def current_settling(i: np.ndarray, v: np.ndarray, sw: Switching) -> int:
    """Samples the current ``i`` takes, after each of ``v``'s transitions, to settle.

    A jump ``J`` of the winding voltage bends the current (its slope changes
    by ``J/L``). Sampled without a filter, the bend is over within the
    jump's interval: the next sample lies on the smooth curve after it, and
    the cubic through the four samples after that predicts it. Behind an
    anti-aliasing filter that the voltage's channel does not share (an
    unfiltered voltage beside a current transducer's active filter), the bend
    rings out over the filter's response, and the samples in it do not relate
    to the voltage as a segment's simulation assumes: unhandled, La read
    +77 % at 2 kHz and +8.6 % at 5 kHz behind a 2nd-order filter at fs/4, at
    6 std. Each sample's miss after a transition, regressed on the
    transition's voltage step over all of the window's transitions, is that
    response; the samples are counted from the first whose regression
    coefficient has fallen below :data:`BEND_SETTLED` of the bend across the
    jump and within three standard errors of zero, and stays there. 0 where
    the first sample after the transition shows no bend (:data:`BEND_SIGMAS`,
    :data:`BEND_SHOWS`): an unfiltered current, or one filtered alike with
    the voltage, whose transitions already hold the bend.
    """
    n = i.shape[0]
    t = sw.transition_mask
    if n < 8 or not np.any(t):
        return 0
    # The cubic through the four samples after each sample predicts it (a quadratic's
    # miss, -i''' dt**3, follows the converter's sine segments, which are locked
    # to the jumps: at 2 kHz as large as a filter's bend).
    right = np.full(n, np.nan)
    right[:-4] = 4.0 * i[1:-3] - 6.0 * i[2:-2] + 4.0 * i[3:-1] - i[4:]
    miss = i - right
    later = np.concatenate([t[1:], [False]])
    earlier = np.concatenate([[False], t[:-1]])
    ends = np.flatnonzero(t & ~later)
    starts = np.flatnonzero(t & ~earlier)
    step = v[ends + 1] - v[starts]
    # tc[j + 4] - tc[e + 1]: transitions among the intervals from e + 1 to j + 3, the ones
    # between a transition's end e and sample j's stencil
    tc = np.concatenate([[0], np.cumsum(t)])
    scale = 0.0
    settled = 0
    last = (0.0, 0.0)
    for m in range(-1, MAX_CURRENT_SETTLING + 1):
        j = ends + 1 + m
        ok = np.flatnonzero(j + 4 < n)
        clear = ok[(tc[j[ok] + 4] - tc[ends[ok] + 1]) == 0]
        x = step[clear]
        y = miss[j[clear]]
        if x.size < max(8, ends.shape[0] // 4) or not np.all(np.isfinite(y)):
            # Most transitions are followed by the next within m + 5 samples: the bend
            # is followed on from its last two samples' geometric decay.
            if m <= 0 or settled < m:
                return settled
            if m == 1:
                return MAX_CURRENT_SETTLING
            return min(MAX_CURRENT_SETTLING, max(settled, m - 1 + geometric_end(*last, scale)))
        sxx = float(x @ x)
        if not sxx > 0:
            return settled
        c = float(x @ y) / sxx
        r = y - c * x
        se = math.sqrt(float(r @ r) / (x.size - 1) / sxx)
        if m == -1:
            # the sample before the jump, predicted from the four after it: the whole bend
            scale = abs(c)
            continue
        if m == 0 and not (c > BEND_SIGMAS * se and c > BEND_SHOWS * scale):
            return 0
        if abs(c) > max(3.0 * se, BEND_SETTLED * scale):
            settled = max(settled, m + 1)
        last = (last[1], c)
        if m == 1:
            # The bend dies out at least as slowly as its first two samples decay: the
            # samples whose regressions fall under three standard errors early still bias
            # a fit that takes every sample of the window (La -1.4 % at 7 std for a 60 mH
            # armature, whose bend is a third of the P-12's).
            settled = max(settled, geometric_end(last[0], c, scale))
    return min(settled, MAX_CURRENT_SETTLING)


def geometric_end(c0: float, c1: float, scale: float) -> int:
    """Samples until a bend ``c0, c1, ...`` decaying geometrically falls below
    :data:`BEND_SETTLED` of ``scale``."""
    ratio = min(max(abs(c1) / abs(c0), 1e-3), 0.9)
    more = math.log(BEND_SETTLED * scale / abs(c0)) / math.log(ratio)
    return max(1, math.ceil(more))


def settle_current(i: np.ndarray, v: np.ndarray, sw: Switching, at_least: int = 0) -> Switching:
    """``sw`` with each transition widened forward by :func:`current_settling` intervals,
    and by ``at_least``."""
    return sw.widened(max(current_settling(i, v, sw), at_least))


#: Images of the sample rate summed for the aliasing factor (|H| of a real filter has fallen
#: far below the 1/(pi*m) it is weighed with long before).
ALIAS_IMAGES = 64

#: An unfiltered jump's factor: the sample misses a uniformly placed share of the interval,
#: whose standard deviation is ``sqrt(1/12)``.
BARE_JUMP_ALIAS = math.sqrt(1.0 / 12.0)

#: Jumps are locked to the samples when they recur within this of a whole number of samples.
LOCKED_TOLERANCE = 0.05


def alias_factor(
    response_at: Callable[[np.ndarray], np.ndarray] | None, sample_rate_hz: float
) -> float:
    """One-sigma error of a window's sample mean per volt-sample of a jump, as a share.

    A jump of ``J`` volts at a fraction ``theta`` of an interval adds to the
    mean of the samples, against the mean of the voltage, ``J*dt*sum_m
    H(m*fs) exp(2j*pi*m*theta) / (2j*pi*m)`` summed over the images ``m != 0``
    of the sample rate (the rectangle rule's error for a step seen through the
    front end ``H``): a pair ``+-m`` gives ``|H(m*fs)| sin(2*pi*m*theta + phi_m) / (pi*m)``.
    Nothing places the converter's firings at a particular point between samples, so
    ``theta`` is uniform and the error's standard deviation is
    ``J*dt*sqrt(sum_m |H(m*fs)|^2 / (2*pi^2*m^2))``; an unfiltered jump gives
    ``J*dt*sqrt(1/12)`` (:data:`BARE_JUMP_ALIAS`). The worst place errs by at most
    ``J*dt*sum_m |H(m*fs)| / (pi*m)``: 1.4 times the standard deviation behind a
    Butterworth at fs/4, 1.8 times behind an RC at fs/4, so a std built on this stays
    within the 2.5 std a quality gate allows wherever the firings fall.
    ``response_at(f_hz)`` is the voltage channel's complex response; ``None``: not
    configured, :data:`UNKNOWN_FILTER_ALIAS`.
    """
    if response_at is None:
        return UNKNOWN_FILTER_ALIAS
    m = np.arange(1, ALIAS_IMAGES + 1, dtype=float)
    h = np.abs(response_at(m * sample_rate_hz))
    return float(min(BARE_JUMP_ALIAS, np.sqrt(np.sum(np.square(h / m)) / (2.0 * np.pi**2))))


#: Aliasing factor assumed when the voltage channel's front end is not configured but its
#: jumps settle over several samples (filtered): that of a 1st-order RC at fs/4, the weakest
#: anti-aliasing filter in use (0.0569 at any rate; a 2nd-order Butterworth at fs/4 gives
#: 0.0141).
UNKNOWN_FILTER_ALIAS = alias_factor(lambda f: 1.0 / (1.0 + 1j * f / 500.0), 2000.0)


def jump_runs(v: np.ndarray, transitions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The jumps of ``v``: each run of intervals in a transition (``transitions``, as
    :attr:`Switching.transition_mask`) is one jump and its settling; its first interval
    and its size (V, from the sample before the run to the sample after it)."""
    n = v.shape[0]
    if n < 2 or not np.any(transitions):
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    edges = np.diff(np.concatenate([[0], transitions.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)  # one past the run's last interval = sample after it
    # A settling jump can leave a sample or two on its smooth curve by chance: runs so close
    # (a gap of one or two intervals) belong to one jump.
    apart = starts[1:] - ends[:-1] > 2
    starts = starts[np.concatenate([[True], apart])]
    ends = ends[np.concatenate([apart, [True]])]
    return starts, v[np.minimum(ends, n - 1)] - v[starts]


def alias_bias_bound(v: np.ndarray, transitions: np.ndarray, factor: float) -> float:
    """One-sigma size (V) of the error of the window's mean voltage that sampled jumps leave
    (:func:`alias_bias`'s size alone)."""
    return alias_bias(v, transitions, factor)[0]


def alias_bias(v: np.ndarray, transitions: np.ndarray, factor: float) -> tuple[float, bool]:
    """One-sigma size (V) of the error of the window's mean voltage that sampled jumps
    leave, and whether the jumps are locked to the samples.

    ``transitions`` marks the intervals of ``v`` in a transition
    (:attr:`Switching.transition_mask`). Each run of them (a jump and its settling) carries the
    jump ``J`` from the sample before it to the sample after it, and errs the
    sample mean by ``factor*|J|/n`` (one sigma over its place between samples,
    :func:`alias_factor`). Jumps that
    keep their place between samples (a steady bridge whose mains period is
    a whole number of sample periods, as a drive synchronised to its mains
    has: the runs start a constant number of samples apart) err alike and add
    up; jumps that wander over the interval err with random signs and add in
    quadrature. A voltage without transitions: ``(0.0, False)``.

    Locked jumps err alike in every window of the same firing angle too: the
    error is then a bias the windows share, which averaging them does not
    shrink (on a single-phase field bridge at 2 kHz on 50 Hz mains the window
    fits of ``Rf`` are +0.26 % off, the samples' mean of ``vf`` as much above the
    voltage's; wandering jumps, at 60 Hz, leave +0.001 %).
    """
    n = v.shape[0]
    if n < 2 or not np.any(transitions):
        return 0.0, False
    starts, jumps = jump_runs(v, transitions)
    spacing = np.diff(starts)
    # Locked: the runs recur every whole number of samples (a field bridge on 50 Hz at
    # 2 kHz: every 10), so each one falls at the same place between samples. A 6-pulse
    # bridge at 2 kHz (6.67 samples per pulse) cycles through three places whose errors
    # cancel in the first images: in quadrature is then the closer account.
    locked = False
    if spacing.size >= 2:
        period = float(np.median(spacing))
        k = np.round((starts - starts[0]) / period)
        # (k never falls: the runs are in order, so its distinct values are its steps.)
        if period > 0 and np.count_nonzero(np.diff(k)) >= 2:
            # The least-squares line through (k, starts), in closed form (np.polyfit's
            # SVD cost a tenth of a millisecond a piece, eight pieces a window).
            kc = k - k.mean()
            slope = float(kc @ (starts - starts.mean())) / float(kc @ kc)
            intercept = float(starts.mean()) - slope * float(k.mean())
            residual = np.abs(starts - (slope * k + intercept))
            locked = bool(
                abs(slope - round(slope)) <= LOCKED_TOLERANCE and np.median(residual) <= 1.5
            )
    total = float(np.sum(np.abs(jumps))) if locked else float(np.sqrt(np.sum(jumps**2)))
    return factor * total / n, locked


#: Half-width of a mains harmonic's band: the grid's frequency wanders (a mine's
#: own generators by up to ~0.5 %), plus the window's spectral leakage (bins).
MAINS_DRIFT = 0.005
MAINS_LEAKAGE_BINS = 2.0

#: The fluctuation below this frequency (Hz) is the drive's control and the load, not ripple.
RIPPLE_FLOOR_HZ = 20.0

#: Harmonics up to this frequency (Hz) are looked at: a bridge's ripple lives in its lowest
#: ones, and more bands would hold a larger share of mere noise.
RIPPLE_CEILING_HZ = 2000.0


def mains_ripple_share(v: np.ndarray, dt: float, *, harmonic_step: int = 1) -> float:
    """Excess share of a voltage's fluctuation power at mains harmonics (the larger of 50/60 Hz).

    A thyristor bridge's terminal voltage repeats every firing: its
    fluctuation above the control's band sits at multiples of the mains
    frequency (100/120 Hz for a single-phase bridge, 300/360 Hz for a
    6-pulse one). A drive's held reference, or white noise, puts about the
    bands' share of the spectrum there; a converter's measured terminals put
    most of it there. The share is returned above the bands' own: 0 for a
    flat spectrum, 1 for pure ripple. Harmonics below Nyquist and
    :data:`RIPPLE_CEILING_HZ` only (aliases of higher ones land off the bands
    unless the rate is a multiple of the mains). ``harmonic_step``: 1, every harmonic from the
    2nd (any bridge: a half-controlled one's 3rd too); 6, a 6-pulse bridge's only (multiples of
    6 x mains).
    """
    x = np.asarray(v, dtype=np.float64)
    n = x.shape[0]
    if n < 16 or not np.all(np.isfinite(x)):
        return 0.0
    t = np.arange(n, dtype=np.float64)
    x = x - np.polyval(np.polyfit(t, x, 1), t)
    above, window, bands = _ripple_bands(n, float(dt), harmonic_step)
    power = np.abs(np.fft.rfft(x * window)) ** 2
    total = float(power[above].sum())
    if not total > 0.0:
        return 0.0
    best = 0.0
    for in_band, flat in bands:
        share = float(power[in_band].sum()) / total
        best = max(best, (share - flat) / (1.0 - flat))
    return best


@functools.lru_cache(maxsize=16)
def _ripple_bands(
    n: int, dt: float, harmonic_step: int = 1
) -> tuple[np.ndarray, np.ndarray, tuple[tuple[np.ndarray, float], ...]]:
    """For :func:`mains_ripple_share` on ``n`` samples at period ``dt`` (a window's length
    repeats, so cached): the bins above the floor, the Hann window, and per mains frequency
    the bins of its harmonics' bands (every ``harmonic_step``-th, from the 2nd or the
    ``harmonic_step``-th) with the share a
    flat spectrum puts there."""
    f = np.fft.rfftfreq(n, dt)
    above = f >= RIPPLE_FLOOR_HZ
    bin_hz = 1.0 / (n * dt)
    nyquist = 0.5 / dt
    bands = []
    for mains in MAINS_HZ:
        first = 2.0 if harmonic_step == 1 else float(harmonic_step)
        harmonics = np.arange(first, min(nyquist, RIPPLE_CEILING_HZ) / mains, harmonic_step)
        harmonics = harmonics * mains
        if harmonics.size == 0:
            continue
        width = MAINS_DRIFT * harmonics + MAINS_LEAKAGE_BINS * bin_hz
        nearest = np.abs(f[:, None] - harmonics[None, :]) <= width[None, :]
        in_band = above & nearest.any(axis=1)
        # What a flat spectrum would put in the bands, taken off (short windows' bands
        # are wide): 0 for noise, 1 for pure ripple.
        flat = float(np.count_nonzero(in_band)) / max(float(np.count_nonzero(above)), 1.0)
        if flat < 1.0:
            in_band.flags.writeable = False
            bands.append((in_band, flat))
    above.flags.writeable = False
    window = np.hanning(n)
    window.flags.writeable = False
    return above, window, tuple(bands)


def segments_between(jumps: np.ndarray, min_length: int = MIN_SEGMENT) -> Segments:
    """Maximal runs of samples whose intervals hold no jump; short runs dropped."""
    n = jumps.shape[0] + 1
    starts: list[int] = []
    ends: list[int] = []
    k = 0
    while k < n:
        s = k
        while k < n - 1 and not jumps[k]:
            k += 1
        # samples s..k are joined by jump-free intervals
        if k - s + 1 >= min_length:
            starts.append(s)
            ends.append(k)
        k += 1
    if not starts:
        return Segments(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), n)
    return Segments(np.array(starts, dtype=np.int64), np.array(ends, dtype=np.int64), n)


#: Fewest isolated samples at one extreme value that can show a clamp (:func:`rail_samples`): three
#: recurred in 4 of 270 simulated recordings at 0.2 % noise where no sample reached the rail.
CLAMPED_MIN = 5
#: How far below a clamped extreme (a share of it) the samples on one side of it lie, at the
#: median: a filter's overshoot falls back by its size (a 4th-order Butterworth's 11 %), or the
#: sample is across the jump; a sine's rounded top sampled 9-11 degrees apart (50-60 Hz mains
#: at 2 kHz) falls by 1.2-1.8 %.
CLAMPED_DEPTH = 0.05


def _clamped(y: np.ndarray, at: np.ndarray) -> bool:
    """Whether isolated samples of ``y`` at its extreme (``at``) are clamped: the value recurs
    exactly, more than twice as often as all values within three quantisation steps below it
    (the window's smallest difference of values: a noisy level spreads over them), while the
    samples on one side of it lie well below it (:data:`CLAMPED_DEPTH`) and scatter by more
    than three steps. A peak repeated by a waveform sampled in step with its period repeats
    its neighbours as well; a sine's rounded top, repeated in a noise-free recording whose
    firing angle moves, has them close by."""
    idx = np.flatnonzero(at)
    if idx.size < CLAMPED_MIN:
        return False
    values = np.unique(y)
    if values.size < 2:
        return False
    step = float(np.min(np.diff(values)))
    extreme = float(y[idx[0]])
    if idx.size <= 2 * np.count_nonzero((y < extreme) & (y >= extreme - 3.0 * step)):
        return False
    for beside in (idx[idx + 1 < y.shape[0]] + 1, idx[idx > 0] - 1):
        if beside.size < CLAMPED_MIN:
            continue
        near = y[beside]
        deep = extreme - float(np.median(near)) > CLAMPED_DEPTH * abs(extreme)
        # (And beyond a float's rounding: an unquantised, noise-free waveform's repeats.)
        scatter = float(np.ptp(near))
        if deep and scatter > 3.0 * step and scatter > 1e-6 * abs(extreme):
            return True
    return False


def rail_samples(x: np.ndarray) -> np.ndarray:
    """Samples at an ADC's rail: the channel clipped, its value says nothing beyond the rail.

    A clipped channel piles up at its extreme value: the largest (or
    smallest) value of the window occurs more than twice as often as all
    values within three quantisation steps below it together (a rounded
    sine top spreads over those steps) and is held for consecutive samples,
    or recurs in isolated samples whose neighbours scatter
    (:func:`_clamped`): a filter's overshoot after each of a converter's
    jumps, clipped one sample a pulse (a 4th-order Butterworth's 11 %
    on a field bridge in inversion, where the jump ends near the supply's
    peak: 0.2-1 V of error in the field voltage's mean that changed with
    the firing angle, and Lf read from a window across a change of the
    field's level +2 % off at 7 std). A periodic waveform sampled in step
    with its period repeats its peak and its peak's neighbours alike. Only
    extremes at the channel's largest magnitude count, so a current resting
    at zero in discontinuous conduction is never taken for a rail.

    A channel that holds one value over the whole window is not taken for clipped: nothing
    tells a rail from a steady noise-free signal (the ideal drive's field current at
    ``--noise 0``, whose every sample was left out, and the whole recording with it). A stuck
    sensor is warned of when the recording is read.
    """
    out = np.zeros(x.shape[0], dtype=bool)
    if x.shape[0] < 3 or bool(np.all(x == x[0])):
        return out
    peak = float(np.max(np.abs(x)))
    if not peak > 0:
        return out
    for sign in (1.0, -1.0):
        y = sign * x
        extreme = float(np.max(y))
        if extreme < 0.5 * peak:
            continue
        at = y == extreme
        count = int(np.count_nonzero(at))
        if count < 2:
            continue
        below = np.unique(y[(y < extreme) & (y > extreme - 0.01 * peak)])
        step = float(np.min(np.diff(np.append(below, extreme)))) if below.size else 0.0
        near = int(np.count_nonzero((y < extreme) & (y >= extreme - 3.0 * step))) if step else 0
        held = bool(np.any(at[1:] & at[:-1]))
        if (count > 2 * near and held) or (not held and _clamped(y, at)):
            out |= at
    return out


def restrict(segments: Segments, valid: np.ndarray, min_length: int = MIN_SEGMENT) -> Segments:
    """``segments`` cut where ``valid`` is False (those samples leave the segments)."""
    if bool(np.all(valid)):
        return segments
    ok = np.asarray(valid, dtype=bool)
    starts: list[np.ndarray] = []
    ends: list[np.ndarray] = []
    for s, e in zip(segments.starts, segments.ends, strict=True):
        # The runs of valid samples in the segment (first, last), at least min_length long.
        edges = np.diff(np.concatenate(([0], ok[s : e + 1].astype(np.int8), [0])))
        first = np.flatnonzero(edges == 1)
        last = np.flatnonzero(edges == -1) - 1
        keep = last - first + 1 >= min_length
        starts.append(first[keep] + s)
        ends.append(last[keep] + s)
    n = segments.n_samples
    if not starts:
        return Segments(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), n)
    return Segments(
        np.concatenate(starts).astype(np.int64), np.concatenate(ends).astype(np.int64), n
    )


def hold_moments(v: np.ndarray) -> np.ndarray:
    """Moments of a voltage held at each sample's value over the following period."""
    mu = np.zeros((v.shape[0] - 1, 3))
    mu[:, 0] = v[:-1]
    return mu


def averaged_moments(v: np.ndarray) -> np.ndarray:
    """Moments of interval ``k`` from a voltage averaged over each period ending at a sample.

    ``v[k+1]`` is the exact mean over interval ``k``; the quadratic whose means
    over intervals ``k-1, k, k+1`` are ``v[k], v[k+1], v[k+2]`` gives the
    first and second Legendre moments: ``(v[k+2] - v[k])/12`` and
    ``(v[k+2] - 2 v[k+1] + v[k])/60`` (linear at the window's end).
    """
    n = v.shape[0]
    mu = np.zeros((n - 1, 3))
    mu[:, 0] = v[1:]
    if n >= 3:
        mu[:-1, 1] = (v[2:] - v[:-2]) / 12.0
        mu[:-1, 2] = (v[2:] - 2.0 * v[1:-1] + v[:-2]) / 60.0
        mu[-1, 1] = (v[-1] - v[-2]) / 6.0
    return mu


def cubic_moments(v: np.ndarray, segments: Segments, shift: float = 0.0) -> np.ndarray:
    """Moments of the segment-wise cubic through ``v``, read ``shift`` periods late."""
    mu = np.zeros((v.shape[0] - 1, 3))
    ik.interpolated_moments(
        np.ascontiguousarray(v, dtype=np.float64), segments.starts, segments.ends,
        float(shift), ik.GAUSS_U, ik.GAUSS_W, mu,
    )  # fmt: skip
    return mu


#: Segments shorter than this keep the cubic: their spectrum is too coarse.
MIN_SPECTRAL_SEGMENT = 16

#: Segments of this many samples or more are mirrored about the half sample past each end
#: (2m samples: a fast FFT length for windows of round length), shorter ones about their end
#: samples (2m - 2). The two differ only in the segment's first and last intervals: on
#: 1 s windows every whole-recording estimate of the converter benches came out the same to
#: the digit, while a 2 kHz window's FFT took a tenth of the time (10 s recordings, 3 seeds).
#: Short segments (between a bridge's firings) keep the mirror they were measured with: there
#: the ends are a large share of the samples, and the half-sample mirror moved Rf of a bare
#: field voltage at 2 kHz from 0.8 % to 1.7 %.
HALF_SAMPLE_MIRROR = 512


#: A voltage whose samples sit (this share of them, within :data:`PWM_LEVEL_TOLERANCE` of
#: its range) at two levels, or three with zero between, is a switched converter's voltage
#: sampled at its output levels: a PWM chopper's terminals without an anti-aliasing filter.
PWM_LEVEL_SHARE = 0.9
PWM_LEVEL_TOLERANCE = 0.05
#: ... and that changes level in this share of the intervals or more is a carrier sampled
#: bare (:func:`pwm_level_changes`); a 2 kHz carrier sampled at 5-10 kHz changes level in
#: 20-40 % of them.
PWM_CHANGES = 0.02


def pwm_level_changes(v: np.ndarray) -> float:
    """Share of intervals over which a voltage sampled at a PWM converter's levels changes level.

    Samples that sit at two levels (the window's extremes) or three (zero between), with at
    least :data:`PWM_LEVEL_SHARE` of them there, are a chopper's terminals sampled bare: each
    sample is the level at its instant, and nothing in the samples says how long the voltage
    stayed there between them (the duty cycle) -- no intersample model can describe it. 0 for
    any other voltage: a bridge's sine pieces, a filtered or held voltage, one level, or
    levels that change in fewer intervals than a carrier would.

    Measured on the simulator's 4-quadrant chopper (2 kHz carrier) sampled bare at 5 and
    10 kHz: 98-99 % of the samples at the levels; a 6-pulse bridge sampled bare, and either
    converter behind a 2nd-order filter at fs/4: no more than 30 %.
    """
    x = np.asarray(v, dtype=np.float64)
    n = x.size
    if n < 3 or not np.all(np.isfinite(x)):
        return 0.0
    # The 0.5th and 99.5th percentiles (order statistics: one partition, no interpolation).
    k_lo, k_hi = int(0.005 * (n - 1)), int(math.ceil(0.995 * (n - 1)))
    part = np.partition(x, (k_lo, k_hi))
    lo, hi = float(part[k_lo]), float(part[k_hi])
    tol = PWM_LEVEL_TOLERANCE * (hi - lo)
    if not tol > 0.0:
        return 0.0
    # Level of each sample: 1 at hi, -1 at lo, 0 at zero (three levels only), else none.
    at_hi = np.abs(x - hi) <= tol
    at_lo = np.abs(x - lo) <= tol
    at_zero = np.abs(x) <= tol if lo + 2 * tol < 0.0 < hi - 2 * tol else np.zeros(n, bool)
    on = at_hi | at_lo | at_zero
    if np.count_nonzero(on) < PWM_LEVEL_SHARE * n:
        return 0.0
    level = at_hi.astype(np.int8) - at_lo.astype(np.int8)
    changes = on[1:] & on[:-1] & (level[1:] != level[:-1])
    return float(np.count_nonzero(changes)) / (n - 1)


@functools.lru_cache(maxsize=32)
def _legendre_responses(n: int) -> np.ndarray:
    """``(3, n // 2 + 1)``: the three interval moments of ``exp(j w u)``, ``u`` in [0, 1], at the
    real FFT's bins (read-only; a window's length repeats, so it is cached)."""
    x, w = np.polynomial.legendre.leggauss(12)
    u = 0.5 * (x + 1.0)
    legendre = np.stack([np.ones_like(u), 2.0 * u - 1.0, 6.0 * u * u - 6.0 * u + 1.0], axis=1)
    omega = 2.0 * np.pi * np.fft.rfftfreq(n)
    out = np.ascontiguousarray((np.exp(1j * np.outer(omega, u)) @ (0.5 * w[:, None] * legendre)).T)
    out.flags.writeable = False
    return out


def smooth_moments(v: np.ndarray, segments: Segments, shift: float = 0.0) -> np.ndarray:
    """Moments of the band-limited interpolant of ``v`` per segment, read ``shift`` periods late.

    Each segment is extended by its mirror image (so that its ends join
    without a jump: about its end samples, or from :data:`HALF_SAMPLE_MIRROR`
    samples on about the half sample past them) and its spectrum multiplied
    by the interval moments of every frequency
    (``int_0^1 exp(j w (k + shift + u)) P_n(2u - 1) du``), which gives the
    moments of the band-limited reconstruction of every interval at once.
    Segments shorter than :data:`MIN_SPECTRAL_SEGMENT` samples keep the cubic
    (:func:`cubic_moments`).
    """
    lengths = segments.ends - segments.starts + 1
    short = lengths < MIN_SPECTRAL_SEGMENT
    mu = cubic_moments(
        v, Segments(segments.starts[short], segments.ends[short], segments.n_samples), shift
    )
    x = np.asarray(v, dtype=np.float64)
    for st, en in zip(segments.starts[~short], segments.ends[~short], strict=True):
        m = int(en) - int(st) + 1
        spectrum, n = _mirrored_spectrum(x[st : en + 1], shift)
        moments = np.fft.irfft(spectrum[None, :] * _legendre_responses(n), n, axis=1)
        mu[st:en, :] = moments[:, : m - 1].T
    return mu


def _mirrored_spectrum(seg: np.ndarray, shift: float) -> tuple[np.ndarray, int]:
    """Half the spectrum of a segment extended by its mirror image, read ``shift`` periods
    late (the moments are real: the response of -w is the conjugate of w's), and the
    extension's length.

    A long segment (:data:`HALF_SAMPLE_MIRROR`) is mirrored about the half sample past each
    end: 2m samples, a fast FFT for a window of round length (2000 samples: 4000), where
    mirrored about its end samples 3998 = 2 * 1999 took ten times as long. Where 2m has a
    large prime factor (a window split into two segments: 2 * 4027 = 8054) the extension
    is made up to the next length of small factors (:func:`fast_length`; 8064) by holding
    each end's sample a few samples longer where it meets its mirror image: the FFT of
    8054 samples took 0.9 ms and its inverse of three rows 1.4 ms, of 8064 0.07 and 0.13.
    """
    m = seg.shape[0]
    if m >= HALF_SAMPLE_MIRROR:
        pad = fast_length(2 * m) - 2 * m
        a = pad // 2
        ext = np.concatenate([seg, np.full(a, seg[-1]), seg[::-1], np.full(pad - a, seg[0])])
    else:
        ext = np.concatenate([seg, seg[-2:0:-1]])
    spectrum = np.fft.rfft(ext)
    if shift != 0.0:
        spectrum = spectrum * np.exp(1j * 2.0 * np.pi * np.fft.rfftfreq(ext.shape[0]) * shift)
    return spectrum, ext.shape[0]


#: The prime factors of the FFT lengths :func:`fast_length` picks (numpy's pocketfft has
#: passes for each; a larger prime factor falls back to Bluestein's algorithm, 10-25x slower).
FAST_FACTORS = (2, 3, 5, 7, 11)


@functools.lru_cache(maxsize=256)
def fast_length(n: int) -> int:
    """The smallest length ``>= n`` whose prime factors are all in :data:`FAST_FACTORS`
    (within 0.2 % of ``n`` above a few thousand)."""
    length = max(int(n), 1)
    while True:
        rest = length
        for p in FAST_FACTORS:
            while rest % p == 0:
                rest //= p
        if rest == 1:
            return length
        length += 1


def smooth_moments_through(
    v: np.ndarray,
    segments: Segments,
    shift: float,
    responses: Sequence[Callable[[int], np.ndarray]],
) -> list[np.ndarray]:
    """:func:`smooth_moments` of ``v`` seen through each of ``responses``, from one spectrum.

    Each response gives, for an extension of ``n`` samples, the filter's
    complex gain at the real FFT's bins. A segment's mirrored extension is
    transformed once and multiplied by each response (the moments of the
    filtered band-limited interpolant); short segments keep the cubic of the
    filtered samples.
    """
    lengths = segments.ends - segments.starts + 1
    short = lengths < MIN_SPECTRAL_SEGMENT
    x = np.asarray(v, dtype=np.float64)
    outs = [np.zeros((x.shape[0] - 1, 3)) for _ in responses]
    if short.any():
        few = Segments(segments.starts[short], segments.ends[short], segments.n_samples)
        ext = np.concatenate([x, x[-2:0:-1]])
        spectrum = np.fft.rfft(ext)
        for out, response in zip(outs, responses, strict=True):
            filtered = np.fft.irfft(spectrum * response(ext.shape[0]), ext.shape[0])[: x.shape[0]]
            out += cubic_moments(filtered, few, shift)
    for st, en in zip(segments.starts[~short], segments.ends[~short], strict=True):
        m = int(en) - int(st) + 1
        spectrum, n = _mirrored_spectrum(x[st : en + 1], shift)
        legendre = _legendre_responses(n)
        for out, response in zip(outs, responses, strict=True):
            moments = np.fft.irfft((spectrum * response(n))[None, :] * legendre, n, axis=1)
            out[st:en, :] = moments[:, : m - 1].T
    return outs


@dataclass(frozen=True)
class InputModel:
    """A window's winding input, as the moment kernels take it.

    Attributes
    ----------
    model : {"hold", "smooth", "switched"}
    mu : (n - 1, 3) array
        Legendre moments of the winding voltage per interval (V).
    segments : Segments
    shift : float
        Relative delay of the voltage behind the current (sample periods).
    switching : Switching or None
        What :func:`find_switching` found in the voltage.
    """

    model: str
    mu: np.ndarray
    segments: Segments
    shift: float = 0.0
    switching: Switching | None = None


def build_input(
    v: np.ndarray,
    model: str,
    *,
    shift: float = 0.0,
    switching: Switching | None = None,
    valid: np.ndarray | None = None,
    dt: float | None = None,
) -> InputModel:
    """The :class:`InputModel` of voltage samples ``v`` under ``model``.

    ``valid`` (per sample) marks the samples that can be used: a clipped
    voltage or current sample leaves the segments, and the simulation
    restarts after it. ``dt``: the sample period (see :func:`find_switching`).
    """
    n = v.shape[0]
    if model not in MODELS:
        raise ValueError(f"unknown intersample model {model!r}; expected one of {MODELS}")
    sw = switching
    if model == "switched":
        sw = switching if switching is not None else find_switching(v, dt)
        segments = segments_between(sw.transition_mask)
    else:
        segments = Segments.whole(n)
    if valid is not None:
        segments = restrict(segments, valid)
    if model == "hold":
        return InputModel("hold", hold_moments(v), segments, 0.0, sw)
    if model == "averaged":
        return InputModel("averaged", averaged_moments(v), segments, 0.0, sw)
    return InputModel(model, smooth_moments(v, segments, shift), segments, shift, sw)


def choose_model(
    v: np.ndarray, requested: str = "auto", dt: float | None = None, *, filtered: bool = False
) -> tuple[str, Switching]:
    """The intersample model for voltage samples ``v``: ``requested``, or decided from the data.

    ``auto``: ``switched`` when the voltage shows clean jumps (an unfiltered
    converter voltage), else ``smooth`` (a filtered one, or no converter). A
    filtered jump still errs the samples' mean by the part of it the filter
    lets alias (up to 0.4 % of a steady field bridge's voltage behind a
    2nd-order filter at fs/4, when the firing instants keep their place
    between samples); the uncertainty carries that error's size
    (:func:`alias_bias_bound`) rather than segmenting, which leaves the
    field's resistance to short segments that pin it worse (-1.6 % at 0.6 %
    std against -0.4 % on the same windows), for the field and the armature alike.
    ``hold`` is never chosen here: only the current can tell a held
    voltage from a sampled one (see :func:`observer.estimation.stages.hold_or_smooth`).
    ``dt``: the sample period, which lets the jumps be told from mains sine segments
    (:func:`find_switching`). ``filtered``: the voltage's front end is configured with an
    anti-aliasing filter, which spreads every jump over the samples after it: ``switched``
    is then never chosen (a filtered jump sampled at the same place in every pulse of a
    bridge locked to the samples can pass every test of a clean one).
    """
    sw = find_switching(v, dt)
    if requested != "auto":
        if requested not in MODELS:
            raise ValueError(f"unknown intersample model {requested!r}; expected auto or {MODELS}")
        return requested, sw
    return ("switched" if sw.switched and not filtered else "smooth"), sw


def emf_moments(i_f: np.ndarray, omega: np.ndarray, segments: Segments) -> np.ndarray:
    """Moments of ``if*omega`` (A*rad/s): a product of two smooth signals, band-limited."""
    e = np.ascontiguousarray(i_f * omega, dtype=np.float64)
    return smooth_moments(e, segments, 0.0)


__all__ = [
    "alias_bias",
    "alias_bias_bound",
    "jump_runs",
    "alias_factor",
    "MODELS",
    "InputModel",
    "Segments",
    "Switching",
    "build_input",
    "choose_model",
    "averaged_moments",
    "cubic_moments",
    "smooth_moments",
    "emf_moments",
    "find_switching",
    "hold_moments",
    "pwm_level_changes",
    "rail_samples",
    "restrict",
    "segments_between",
    "settle_current",
]
