"""The voltage channel's anti-aliasing filter, identified from the converter's jumps.

Where the front ends are not configured, a window's std must carry the alias of the
converter's jumps through a filter nobody named (:func:`~observer.estimation.intersample.
alias_factor`). Assuming the weakest filter in use, an RC at fs/4, makes it four times that
of the 2nd-order Butterworth a drive more often has, and on a 6-pulse bridge at 2 kHz that
alone kept a 3 % step of ``Ra`` below what a change test can confirm. The jumps themselves
show the filter: between two firings a line-commutated bridge's terminal voltage is a piece
of the mains sine (a back-EMF where the current has stopped, a DC link's level behind a
chopper: about constant), and a linear filter's output is then that piece's steady response
plus the transient that each jump starts, whose shape is the filter's::

    v(t) = A cos wt + B sin wt + C
           + sum_k [a_k gc(t - t_k) + b_k gs(t - t_k) + c_k g1(t - t_k)]

with ``gc``, ``gs``, ``g1`` the filter's responses to a causal ``cos``, ``sin`` and step
(zero before ``t_k``). Per candidate filter (families of :func:`candidates`, cutoffs on a
grid), each stretch of a few jumps is fitted by least squares, each jump's instant ``t_k``
searched between its samples; the candidate with the least residual describes the channel.
Candidates that fit nearly as well (:data:`TIED`) cannot be told apart by the data: the
factor used is the largest of their alias factors.

Measured on the P-12 behind the dual 6-pulse bridge (12-bit ADC, 0.2 % noise, 0.5 s of
voltage): an RC at fs/4 at 2 kHz is read as such (alias 0.057); a 2nd-order Butterworth at
fs/4 as filters whose alias factors are all 0.0142-0.0143 (the Butterworth's is 0.0142);
at 5 and 10 kHz a 4th-order Bessel at fs/4 by a residual 3.7 times below the next family.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from observer.estimation.frontend import filter_sections, sections_response
from observer.estimation.intersample import BARE_JUMP_ALIAS, MAINS_HZ, alias_factor, find_switching

#: Windings whose untold voltage filter is identified and used: both. (The armature's was
#: withdrawn for a while: with the Butterworth's alias in place of the RC's, windows where a
#: converter-fed drive holds its speed read Ra -2.4 % and K +0.5 % at |error/std| up to 4.3,
#: and the tracker confirmed a false "Ra fell 2.4 %". That error is the jumps' common area
#: error, which :func:`observer.estimation.stages.jump_stage` now measures and carries.)
IDENTIFIED_WINDINGS = ("field", "armature")

#: Filter families tried (kind, order) and cutoffs as fractions of the sample rate.
#: (Without the 3rd-order Bessel, one at fs/4 was read as a 2nd-order one at fs/3.5 on the
#: field, and as a 4th-order one with half its alias on the armature: Lf 1 % low at 4 std.)
FAMILIES = (("rc", 1), ("rc", 2), ("butter", 2), ("bessel", 2), ("butter", 3), ("bessel", 3),
            ("butter", 4), ("bessel", 4))  # fmt: skip
CUTOFF_FRACTIONS = (0.1, 0.125, 0.15, 0.175, 0.2, 0.225, 0.25, 0.285, 0.33, 0.38, 0.45)

#: Candidates whose mean squared residual is within this factor of the best are tied: the
#: data does not tell them apart (an RC at fs/4 at 2 kHz: an RC at fs/5 1.01, two RCs at fs/4
#: 1.06; a Butterworth at fs/4: the Bessel at fs/5 fitted best, the Butterworth itself 1.25,
#: and every filter within 1.25 had the same alias factor within 1 %).
TIED = 1.25

#: Jumps per fitted stretch, and samples at most after its last jump.
JUMPS_PER_STRETCH = 3
TAIL_SAMPLES = 12
#: Samples of settled voltage before a stretch's first jump.
LEAD_SAMPLES = 3

#: Jumps used at most (the fit's cost grows with them; 45 tell the families apart).
MAX_JUMPS = 45
#: Fewer jumps than this: not identified.
MIN_JUMPS = 12

#: Not identified where the best fit's residual exceeds this share of the median jump: the
#: voltage is not pieces of a sine and constants between jumps (commutation this model does
#: not follow, a voltage that is not a converter's).
MAX_RESIDUAL_SHARE = 0.05

#: A stretch whose best fit misses by more than this times the median stretch's mean
#: square is left out.
OUTLIER = 4.0

#: Golden-section steps refining a family's cutoff between its grid neighbours, for every
#: family whose best grid point is within this factor of the best candidate's residual.
REFINE_STEPS = 8
REFINED = 3.0

#: The golden section's ratio (both searches: a jump's instant, a family's cutoff).
GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)

#: Each jump's instant is searched over this many points of the two intervals around it,
#: then refined by this many golden-section steps (to 2e-4 of an interval).
GRID = 11
GOLDEN_STEPS = 14


@dataclass(frozen=True)
class FilterFit:
    """What the jumps say of the voltage channel's filter.

    Attributes
    ----------
    alias : float or None
        The aliasing factor to use (:func:`~observer.estimation.intersample.alias_factor`):
        the largest of the tied candidates'; None where not identified.
    best : str
        The best candidate (``butter2@0.250`` = a 2nd-order Butterworth at fs/4).
    tied : tuple of str
        Candidates within :data:`TIED` of the best.
    rms_v : float
        The best candidate's residual (V).
    jumps : int
        Jumps fitted.
    reason : str
        Why not identified ('' where identified).
    """

    alias: float | None
    best: str = ""
    tied: tuple[str, ...] = ()
    rms_v: float = math.nan
    jumps: int = 0
    reason: str = ""

    @property
    def too_few_jumps(self) -> bool:
        """Not identified for want of jumps (another stretch of samples may have them)."""
        return self.alias is None and self.reason.endswith("needed)")

    @property
    def text(self) -> str:
        """The best candidate in the grammar of ``[chain]`` (``butter2@fs/4.00``)."""
        if self.best in ("", "none"):
            return self.best
        kind, order, frac = parse_candidate(self.best)
        return f"{kind}{order}@fs/{1.0 / frac:.2f}"

    def to_dict(self) -> dict[str, object]:
        return {
            "alias": self.alias, "best": self.best, "tied": list(self.tied),
            "rms_v": self.rms_v if math.isfinite(self.rms_v) else None, "jumps": self.jumps,
            "reason": self.reason,
        }  # fmt: skip


def parse_candidate(name: str) -> tuple[str, int, float]:
    """``butter2@0.2500`` -> ``("butter", 2, 0.25)``: a candidate's kind, order and cutoff
    as a fraction of the sample rate."""
    family, frac = name.split("@")
    kind = family.rstrip("0123456789")
    return kind, int(family[len(kind) :]), float(frac)


def candidates(sample_rate_hz: float) -> dict[str, np.ndarray | None]:
    """Name -> filter sections of every candidate (``none``: no filter)."""
    out: dict[str, np.ndarray | None] = {"none": None}
    for kind, order in FAMILIES:
        for frac in CUTOFF_FRACTIONS:
            out[f"{kind}{order}@{frac:.3f}"] = filter_sections(kind, order, frac * sample_rate_hz)
    return out


def poles_residues(sections: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Poles and residues of ``sections``' transfer function, in units of the sample period
    (a repeated pole, an RC cascade's, is split by 1e-5 of itself)."""
    poles: list[complex] = []
    gain = 1.0
    for kind, w0, q in sections:
        if kind == 1:
            poles.append(-w0)
            gain *= w0
        elif kind == 2:
            poles.extend(complex(r) for r in np.roots([1.0, w0 / q, w0 * w0]))
            gain *= w0 * w0
    p = np.array(poles, dtype=np.complex128) * dt
    gain *= dt ** len(poles)
    for i in range(p.shape[0]):
        for j in range(i):
            if abs(p[i] - p[j]) < 1e-6 * abs(p[i]):
                p[i] *= 1.0 + 1e-5 * (i + 1)
    r = np.array(
        [gain / np.prod([pk - pj for j, pj in enumerate(p) if j != k]) for k, pk in enumerate(p)],
        dtype=np.complex128,
    )
    return p, r


@njit(cache=True, nogil=True)
def jump_responses(tau: float, w: float, p: np.ndarray, r: np.ndarray, out: np.ndarray) -> None:
    """The filter's responses at ``tau`` (samples) to a causal cos, sin and step (``p``
    empty: no filter)."""
    if tau <= 0.0:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        return
    if p.shape[0] == 0:
        out[0] = math.cos(w * tau)
        out[1] = math.sin(w * tau)
        out[2] = 1.0
        return
    jw = 1j * w
    e = np.exp(jw * tau)
    g = 0.0 + 0.0j
    s = 0.0 + 0.0j
    for k in range(p.shape[0]):
        ep = np.exp(p[k] * tau)
        g += r[k] * (e - ep) / (jw - p[k])
        s += r[k] * (1.0 - ep) / (-p[k])
    out[0] = g.real
    out[1] = g.imag
    out[2] = s.real


@njit(cache=True, nogil=True)
def _rss(y: np.ndarray, w: float, t0: np.ndarray, p: np.ndarray, r: np.ndarray) -> float:
    """Residual sum of squares of ``y`` on the base and the jumps' responses at ``t0``."""
    n = y.shape[0]
    m = 3 + 3 * t0.shape[0]
    x = np.empty((n, m))
    buf = np.empty(3)
    for i in range(n):
        x[i, 0] = math.cos(w * i)
        x[i, 1] = math.sin(w * i)
        x[i, 2] = 1.0
        for k in range(t0.shape[0]):
            jump_responses(i - t0[k], w, p, r, buf)
            x[i, 3 + 3 * k] = buf[0]
            x[i, 4 + 3 * k] = buf[1]
            x[i, 5 + 3 * k] = buf[2]
    explained = normal_solve(x.T @ x, x.T @ y, np.empty(m))
    if explained < 0.0:
        return np.inf
    return max(float(y @ y) - explained, 0.0)


@njit(cache=True, nogil=True)
def normal_solve(a: np.ndarray, b: np.ndarray, coef: np.ndarray) -> float:
    """Solve the normal equations ``a c = b`` (scaled to unit diagonal, with a small ridge, by
    Cholesky; ``a`` and ``b`` are overwritten) into ``coef``; returns the explained sum of
    squares ``b'c``, or -1 where ``a`` is not positive definite."""
    m = b.shape[0]
    d = np.empty(m)
    for j in range(m):
        d[j] = math.sqrt(a[j, j]) if a[j, j] > 0 else 1.0
    for i in range(m):
        b[i] /= d[i]
        for j in range(m):
            a[i, j] /= d[i] * d[j]
        a[i, i] += 1e-10
    ll = np.zeros((m, m))
    for j in range(m):
        s = a[j, j]
        for k in range(j):
            s -= ll[j, k] * ll[j, k]
        if s <= 0:
            return -1.0
        ll[j, j] = math.sqrt(s)
        for i in range(j + 1, m):
            s = a[i, j]
            for k in range(j):
                s -= ll[i, k] * ll[j, k]
            ll[i, j] = s / ll[j, j]
    z = np.empty(m)
    for i in range(m):
        s = b[i]
        for k in range(i):
            s -= ll[i, k] * z[k]
        z[i] = s / ll[i, i]
    for i in range(m - 1, -1, -1):
        s = z[i]
        for k in range(i + 1, m):
            s -= ll[k, i] * coef[k]
        coef[i] = s / ll[i, i]
    for i in range(m):
        coef[i] /= d[i]
    return float(z @ z)


@njit(cache=True, nogil=True)
def _stretch_rss(
    y: np.ndarray, w: float, starts: np.ndarray, p: np.ndarray, r: np.ndarray, grid: int
) -> float:
    """Least residual of one stretch over its jumps' instants (two sweeps of a grid search
    over the two intervals around each flagged one, refined by golden section)."""
    t0 = starts.astype(np.float64) + 0.5
    best = _rss(y, w, t0, p, r)
    for _sweep in range(2):
        for k in range(starts.shape[0]):
            values = np.empty(grid)
            offsets = np.empty(grid)
            for g in range(grid):
                offsets[g] = -1.0 + 2.0 * g / (grid - 1)
                t0[k] = starts[k] + 0.5 + offsets[g]
                values[g] = _rss(y, w, t0, p, r)
            j = int(np.argmin(values))
            # The residual is sharp in the instant (a 170 V jump misplaced by 1 % of an
            # interval misses by volts): golden-section search around the grid's best.
            h = offsets[1] - offsets[0]
            lo, hi = offsets[j] - h, offsets[j] + h
            x1, x2 = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
            t0[k] = starts[k] + 0.5 + x1
            f1 = _rss(y, w, t0, p, r)
            t0[k] = starts[k] + 0.5 + x2
            f2 = _rss(y, w, t0, p, r)
            for _ in range(GOLDEN_STEPS):
                if f1 < f2:
                    hi, x2, f2 = x2, x1, f1
                    x1 = hi - GOLDEN * (hi - lo)
                    t0[k] = starts[k] + 0.5 + x1
                    f1 = _rss(y, w, t0, p, r)
                else:
                    lo, x1, f1 = x1, x2, f2
                    x2 = lo + GOLDEN * (hi - lo)
                    t0[k] = starts[k] + 0.5 + x2
                    f2 = _rss(y, w, t0, p, r)
            at, value = (x1, f1) if f1 < f2 else (x2, f2)
            if values[j] < value:
                at, value = offsets[j], values[j]
            t0[k] = starts[k] + 0.5 + at
            best = value
    return best


def _stretches(jump_starts: np.ndarray, n: int) -> list[tuple[int, int, np.ndarray]]:
    """(first sample, end, jump intervals relative to the first sample) of stretches: up to
    :data:`JUMPS_PER_STRETCH` jumps each within :data:`TAIL_SAMPLES` of the one before,
    from :data:`LEAD_SAMPLES` before the first to before the next jump's samples move;
    spread evenly over the samples where they hold more than :data:`MAX_JUMPS` jumps (a
    recording's first seconds may all be one operating point)."""
    out = []
    i = 0
    count = jump_starts.shape[0]
    while i < count - 1:
        j = i + 1
        while (
            j < count - 1
            and j - i < JUMPS_PER_STRETCH
            and jump_starts[j] - jump_starts[j - 1] <= TAIL_SAMPLES
        ):
            j += 1
        group = jump_starts[i:j]
        a = int(group[0]) - LEAD_SAMPLES
        b = min(int(jump_starts[j]) - 1, int(group[-1]) + TAIL_SAMPLES, n)
        # Settled before the first jump: the jump before it is further back than a tail.
        settled = i == 0 or jump_starts[i] - jump_starts[i - 1] > LEAD_SAMPLES + 2
        if a >= 0 and settled and b - int(group[-1]) >= 4:
            out.append((a, b, (group - a).astype(np.int64)))
        i = j
    jumps = sum(js.shape[0] for _, _, js in out)
    if jumps > MAX_JUMPS:
        keep = np.unique(np.linspace(0, len(out) - 1, max(1, len(out) * MAX_JUMPS // jumps)))
        out = [out[int(k)] for k in keep.round().astype(int)]
    return out


def mains_frequency(v: np.ndarray, dt: float) -> float:
    """The mains frequency whose sine recurrence predicts ``v`` best."""
    best, scale = MAINS_HZ[0], math.inf
    for hz in MAINS_HZ:
        c2 = 2.0 * math.cos(2.0 * math.pi * hz * dt)
        miss = v[2:] - c2 * v[1:-1] + v[:-2]
        s = float(np.median(np.abs(miss)))
        if s < scale:
            best, scale = hz, s
    return best


def identify_voltage_filter(v: np.ndarray, dt: float) -> FilterFit:
    """Identify the anti-aliasing filter a converter's voltage samples ``v`` were taken
    through (see the module's text); ``alias`` None where the samples do not tell."""
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)] if not np.all(np.isfinite(v)) else v
    n = v.shape[0]
    if n < 64:
        return FilterFit(None, reason="too few samples")
    sw = find_switching(v, dt)
    jumps = sw.jumps
    edges = np.diff(np.concatenate([[0], jumps.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    stretches = _stretches(starts, n)
    used = int(sum(js.shape[0] for _, _, js in stretches))
    if used < MIN_JUMPS:
        return FilterFit(None, jumps=used, reason=f"{used} jumps (at least {MIN_JUMPS} needed)")
    w = 2.0 * math.pi * mains_frequency(v, dt) * dt
    fs = 1.0 / dt
    lengths = np.array([b - a for a, b, _ in stretches], dtype=float)

    def rss_of(sections: np.ndarray | None) -> np.ndarray:
        if sections is None:
            p = np.zeros(0, dtype=np.complex128)
            r = np.zeros(0, dtype=np.complex128)
        else:
            p, r = poles_residues(sections, dt)
        return np.array([_stretch_rss(v[a:b], w, js, p, r, GRID) for a, b, js in stretches])

    grid = candidates(fs)
    names = list(grid)
    table = np.array([rss_of(sections) for sections in grid.values()])
    # Stretches no candidate describes (deep discontinuous conduction: the current's
    # extinction bends the voltage in ways a sine and a constant do not follow) would
    # decide by how badly each misses them: left out.
    per_sample = table.min(axis=0) / lengths
    kept = per_sample <= OUTLIER * float(np.median(per_sample))
    scores = dict(zip(names, table[:, kept].sum(axis=1) / lengths[kept].sum(), strict=True))
    grid_best = min(scores.values())
    for kind, order in FAMILIES:
        family = f"{kind}{order}"
        mine = {k: v for k, v in scores.items() if k.startswith(family + "@")}
        name = min(mine, key=mine.__getitem__)
        if mine[name] > REFINED * grid_best:
            continue
        # The cutoff between the grid's neighbours (golden section in its log): where the
        # transient is over within a sample, families differ in what the data cannot show
        # (an RC at 0.35 fs at 2 kHz fits as well as two RCs at 0.37 fs, whose alias is a
        # quarter less), so every family near the best is refined and the ties compared.
        at = CUTOFF_FRACTIONS.index(parse_candidate(name)[2])
        lo = math.log(CUTOFF_FRACTIONS[max(at - 1, 0)])
        hi = math.log(CUTOFF_FRACTIONS[min(at + 1, len(CUTOFF_FRACTIONS) - 1)])

        def score(log_frac: float, kind: str = kind, order: int = order) -> float:
            key = f"{kind}{order}@{math.exp(log_frac):.4f}"
            if key not in scores:
                rss = rss_of(filter_sections(kind, order, math.exp(log_frac) * fs))
                scores[key] = float(rss[kept].sum() / lengths[kept].sum())
            return scores[key]

        x1, x2 = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
        f1, f2 = score(x1), score(x2)
        for _ in range(REFINE_STEPS):
            if f1 < f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - GOLDEN * (hi - lo)
                f1 = score(x1)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + GOLDEN * (hi - lo)
                f2 = score(x2)
    best = min(scores, key=scores.__getitem__)
    tied = tuple(sorted((k for k, s in scores.items() if s <= TIED * scores[best]),
                        key=scores.__getitem__))  # fmt: skip
    rms = math.sqrt(scores[best])
    used = int(sum(js.shape[0] for (_, _, js), k in zip(stretches, kept, strict=True) if k))
    size = float(np.median(np.abs(v[starts + 2] - v[np.maximum(starts - 1, 0)])))
    if not rms <= MAX_RESIDUAL_SHARE * size:
        return FilterFit(
            None, best, tied, rms, used,
            reason=f"the best fit misses by {rms:.3g} V, {rms / size:.0%} of a jump",
        )  # fmt: skip
    return FilterFit(max(candidate_alias(k, fs) for k in tied), best, tied, rms, used)


def warm_up() -> None:
    """Compile (or load from the numba cache) the fit's kernels with the types
    :func:`identify_voltage_filter` passes."""
    y = np.linspace(0.0, 1.0, 12)
    starts = np.array([4], dtype=np.int64)
    p, r = poles_residues(filter_sections("butter", 2, 500.0), 5e-4)
    _stretch_rss(y, 0.1, starts, p, r, 3)


def candidate_alias(name: str, sample_rate_hz: float) -> float:
    """The aliasing factor of candidate ``name`` (:func:`candidates`) at ``sample_rate_hz``."""
    if name == "none":
        return BARE_JUMP_ALIAS
    kind, order, frac = parse_candidate(name)
    sections = filter_sections(kind, order, frac * sample_rate_hz)
    return alias_factor(lambda f: sections_response(sections, f), sample_rate_hz)
