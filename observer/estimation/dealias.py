"""A filtered converter voltage's jumps, put back between the samples.

The ``smooth`` intersample model reads a filtered voltage between its samples as their
band-limited interpolant (:func:`~observer.estimation.intersample.smooth_moments`). A
converter's voltage is not band-limited: it jumps at every firing, and an anti-aliasing
filter only bends the jump into its step response ``s(t)``, whose spectrum above half the
sample rate folds back into the samples. Where the firings keep their place between the
samples (a bridge on 50 Hz mains sampled at a multiple of its pulse rate: a single-phase
field bridge at 2, 5 or 10 kHz) every jump's alias is the same and lands on the ripple's
own harmonics, which the winding's inductance is read from. On a P-12 field behind a
1st-order RC at fs/4, sampled at 2 kHz, the field inductance read from 30 s was -2.8 %
(|error/std| 2.3); the same drive on 50.3 Hz mains (firings wandering over the interval)
+0.13 %.

The jumps themselves are seen in the samples, and so is the filter (configured, or
identified from these same jumps: :mod:`observer.estimation.filter_id`). Between firings a
line-commutated bridge's voltage is a piece of the mains sine, so about each jump the
filtered samples are::

    y_k = A cos wk + B sin wk + C + a gc(k - t0) + b gs(k - t0) + c g1(k - t0)

with ``gc``, ``gs``, ``g1`` the filter's responses to a causal cos, sin and step. Fitting it
(the jump's instant ``t0`` searched between the samples) gives the jump of the voltage's
value ``J = a + c`` and of its slope ``D = b w``. The moments of every interval are then
corrected by what the band-limited interpolant of a jump's filtered step (and ramp) misses
against the filtered waveform itself::

    mu_k += J E_step(k - t0) + D E_ramp(k - t0)

``E`` is computed once per filter pair and sample period (:func:`correction_table`), through
the same interpolation and relative front-end filter the problem applies, so the correction is
of exactly the error made. On that 2 kHz recording Lf then reads +0.05 % and Rf -0.01 %.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from observer.estimation.filter_id import (
    GOLDEN,
    jump_responses,
    mains_frequency,
    normal_solve,
    parse_candidate,
    poles_residues,
)
from observer.estimation.frontend import FrontEnd, apply_relative, filter_sections
from observer.estimation.intersample import Segments, smooth_moments

#: Windings whose filtered jumps are put back: the field, whose single-phase bridge's firings
#: lock to the samples at every common rate on 50 Hz mains. Not the armature: its 6-pulse
#: jumps come 6.7 samples apart at 2 kHz, too close to fit one by one, and at 5 and 10 kHz,
#: where they can be fitted, putting them back took the held-speed windows' Ra from +3.0 to
#: +0.65 % but left more of the other windows' published Ra outside 2.5 std (P-12,
#: ``bench.window_honesty``: 86-93 % untold behind an RC or beside a Bessel current filter,
#: 89-98 % configured, against 98-100 % without). Its common area error is carried instead
#: (:func:`~observer.estimation.stages.jump_stage`).
WINDINGS = ("field",)

#: Intervals on each side of a jump whose moments are corrected (the interpolant's error
#: falls as the square of the distance: at 32 intervals below 1e-3 of its peak).
HALF_WIDTH = 32
#: Places of a jump between two samples at which the correction is tabulated (linear
#: interpolation between them).
FRACTIONS = 101
#: Samples fitted before and after a jump's first flagged interval (fewer where the next jump
#: comes sooner), and the fewest a jump's fit needs (six coefficients and its instant).
LEAD = 3
TAIL = 9
MIN_SAMPLES = 9
#: A jump's instant is searched from this many samples before its first flagged interval to
#: this many after (a filtered jump late in an interval may flag only the next one), on a grid
#: of :data:`GRID` points refined by golden section.
SEARCH_BEFORE = 1.0
SEARCH_AFTER = 1.5
GRID = 11
GOLDEN_STEPS = 10

#: Fewer of a window's jumps fitted than this share (jumps closer together than a fit needs:
#: a chopper switching near the sample rate), nothing is put back.
MIN_FITTED_SHARE = 0.8

#: Share of the uncorrected alias a window's std still carries for corrected jumps. Against
#: the filtered waveform itself (a single-phase bridge at 2 kHz, ``tests/.../test_dealias.py``)
#: the corrected moments' error at the pulse rate and of the mean was 1/22 and 1/34 of the
#: interpolant's behind an RC at fs/4, 1/4.4 and 1/10 behind a 2nd-order Butterworth.
RESIDUAL_ALIAS = 0.25


@njit(cache=True, nogil=True)
def _base(y: np.ndarray, w: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sine base's columns (cos, sin, 1) over ``y``'s samples, their Gram block and
    their products with ``y``: the part of a jump's fit that its instant leaves."""
    m = y.shape[0]
    x = np.empty((m, 3))
    g = np.zeros((3, 3))
    b = np.zeros(3)
    for a in range(m):
        x[a, 0] = math.cos(w * a)
        x[a, 1] = math.sin(w * a)
        x[a, 2] = 1.0
        for j in range(3):
            b[j] += x[a, j] * y[a]
            for k in range(3):
                g[j, k] += x[a, j] * x[a, k]
    return x, g, b


@njit(cache=True, nogil=True)
def _jump_rss(
    y: np.ndarray,
    t0: float,
    w: float,
    p: np.ndarray,
    r: np.ndarray,
    base: tuple[np.ndarray, np.ndarray, np.ndarray],
    coef: np.ndarray,
) -> float:
    """Least squares of ``y`` on the sine base (:func:`_base`) and one jump's responses at
    ``t0`` (samples from ``y``'s first); the coefficients go to ``coef`` (cos, sin, 1, gc, gs,
    g1)."""
    m = y.shape[0]
    xb, gb, bb = base
    row = np.empty(6)
    buf = np.empty(3)
    g = np.zeros((6, 6))
    b = np.zeros(6)
    for j in range(3):
        b[j] = bb[j]
        for k in range(3):
            g[j, k] = gb[j, k]
    for a in range(m):
        row[0] = xb[a, 0]
        row[1] = xb[a, 1]
        row[2] = 1.0
        jump_responses(a - t0, w, p, r, buf)
        row[3] = buf[0]
        row[4] = buf[1]
        row[5] = buf[2]
        for j in range(3, 6):
            b[j] += row[j] * y[a]
            for k in range(j + 1):
                g[j, k] += row[j] * row[k]
    for j in range(6):
        for k in range(j + 1, 6):
            g[j, k] = g[k, j]
    explained = normal_solve(g, b, coef)
    if explained < 0.0:
        return np.inf
    return max(float(y @ y) - explained, 0.0)


@njit(cache=True, nogil=True)
def _fit_one(
    y: np.ndarray, s: int, w: float, p: np.ndarray, r: np.ndarray, out: np.ndarray
) -> bool:
    """Fit the jump whose first flagged interval is ``s`` of ``y`` (indices from 0, so the
    fit depends on the samples alone); ``out`` gets ``(t0, J, D)``; False: not fitted."""
    coef = np.empty(6)
    base = _base(y, w)
    best_t, best = 0.0, np.inf
    step = (SEARCH_BEFORE + SEARCH_AFTER) / (GRID - 1)
    for g in range(GRID):
        t = s - SEARCH_BEFORE + g * step
        f = _jump_rss(y, t, w, p, r, base, coef)
        if f < best:
            best, best_t = f, t
    a, b = best_t - step, best_t + step
    x1, x2 = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
    f1 = _jump_rss(y, x1, w, p, r, base, coef)
    f2 = _jump_rss(y, x2, w, p, r, base, coef)
    for _ in range(GOLDEN_STEPS):
        if f1 < f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - GOLDEN * (b - a)
            f1 = _jump_rss(y, x1, w, p, r, base, coef)
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + GOLDEN * (b - a)
            f2 = _jump_rss(y, x2, w, p, r, base, coef)
    t = x1 if f1 < f2 else x2
    if min(f1, f2) > best:
        t = best_t
    if not math.isfinite(_jump_rss(y, t, w, p, r, base, coef)):
        return False
    out[0] = t
    out[1] = coef[3] + coef[5]
    out[2] = coef[4] * w
    return True


#: Fits kept for the next windows (a sliding window sees each jump several times): at most
#: this many, keyed by the jump's samples, so a fit is the same whether found or kept.
CACHE_SIZE = 4096
_cache: dict[tuple[object, ...], tuple[float, float, float] | None] = {}


#: Samples the mains frequency is decided from.
MAINS_SAMPLES = 4096


@functools.lru_cache(maxsize=16)
def _poles(sections: bytes, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`~observer.estimation.filter_id.poles_residues` of ``sections`` (as bytes)."""
    return poles_residues(np.frombuffer(sections, dtype=np.float64).reshape(-1, 3), dt)


def fit_jumps(v: np.ndarray, dt: float, sections: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``(m, 3)``: each fitted jump's instant (samples), value jump (V) and slope jump (V per
    sample) of ``v`` seen through filter ``sections``, from its first flagged intervals
    ``starts`` (:func:`~observer.estimation.intersample.jump_runs`). Each jump is fitted on
    the samples from :data:`LEAD` before it to :data:`TAIL` after it, short of its
    neighbours' (too few of them: left out)."""
    x = np.ascontiguousarray(v, dtype=np.float64)
    n = x.shape[0]
    count = starts.shape[0]
    rows: list[tuple[float, float, float]] = []
    if count == 0:
        return np.empty((0, 3))
    filter_key = sections.tobytes()
    p, r = _poles(filter_key, dt)
    # (50 or 60 Hz: a few thousand samples decide it as well as the window.)
    w = 2.0 * math.pi * mains_frequency(x[:MAINS_SAMPLES], dt) * dt
    setup = (filter_key, dt, w)
    buf = np.empty(3)
    at = [int(k) for k in starts]
    for k, s in enumerate(at):
        lo = max(s - LEAD, at[k - 1] + LEAD + 2 if k > 0 else 0, 0)
        hi = min(s + TAIL, at[k + 1] - 1 if k + 1 < count else n - 1, n - 1)
        if hi - lo + 1 < MIN_SAMPLES or lo > s - 1:
            continue
        y = x[lo : hi + 1]
        key = (setup, s - lo, y.tobytes())
        if key in _cache:
            fit = _cache[key]
        else:
            fit = (
                (float(buf[0]), float(buf[1]), float(buf[2]))
                if _fit_one(y, s - lo, w, p, r, buf)
                else None
            )
            if len(_cache) >= CACHE_SIZE:
                _cache.clear()
            _cache[key] = fit
        if fit is not None:
            rows.append((lo + fit[0], fit[1], fit[2]))
    return np.array(rows, dtype=np.float64).reshape(-1, 3)


def _step_values(p: np.ndarray, r: np.ndarray, tau: np.ndarray, ramp: bool) -> np.ndarray:
    """The filter's response (poles ``p``, residues ``r`` per sample; none: identity) to a unit
    step (or a ramp of one per sample) starting at ``tau = 0``."""
    out = np.zeros(tau.shape)
    on = tau > 0
    t = tau[on][:, None]
    if p.shape[0] == 0:
        out[on] = t[:, 0] if ramp else 1.0
    elif ramp:
        out[on] = np.real(np.sum(r / (-p) * (t - (np.exp(p * t) - 1.0) / p), axis=1))
    else:
        out[on] = np.real(np.sum(r * (1.0 - np.exp(p * t)) / (-p), axis=1))
    return out


def _exact_moments(p: np.ndarray, r: np.ndarray, start: float, ramp: bool) -> np.ndarray:
    """``(2 HALF_WIDTH + 1, 3)``: the Legendre moments over intervals ``[i, i + 1]``,
    ``i = -HALF_WIDTH..HALF_WIDTH``, of the response to a step (ramp) at ``start``."""
    x, wts = np.polynomial.legendre.leggauss(16)
    rows = np.arange(-HALF_WIDTH, HALF_WIDTH + 1, dtype=float)[:, None]
    # The response bends where it starts: each interval is integrated on each side of that
    # point (one side empty where it lies outside).
    cut = np.clip(start - rows, 0.0, 1.0)
    out = np.zeros((rows.shape[0], 3))
    for a, b in ((np.zeros_like(cut), cut), (cut, np.ones_like(cut))):
        u = a + (b - a) * 0.5 * (x[None, :] + 1.0)
        f = _step_values(p, r, (rows + u - start).ravel(), ramp).reshape(u.shape)
        w = (b - a) * 0.5 * wts[None, :] * f
        out[:, 0] += w.sum(axis=1)
        out[:, 1] += (w * (2.0 * u - 1.0)).sum(axis=1)
        out[:, 2] += (w * (6.0 * u * u - 6.0 * u + 1.0)).sum(axis=1)
    return out


#: Samples on each side of the tabulated jump (its interpolant's far ends are negligible).
_TABLE_SAMPLES = 1024


#: Relative delays (sample periods) at which :func:`correction_table` is tabulated; a delay
#: between two of them is read by linear interpolation.
SHIFT_STEP = 0.05


@functools.lru_cache(maxsize=32)
def correction_table(
    voltage: FrontEnd, current: FrontEnd | None, dt: float, shift: float = 0.0
) -> np.ndarray:
    """``(2, FRACTIONS, 2 HALF_WIDTH + 1, 3)``: the moments a unit step (``[0]``) and a unit
    ramp (``[1]``) of the voltage, at each place between two samples, miss when seen through
    ``voltage``'s filter, sampled, interpolated band-limited and (``current`` given and
    different) passed through ``H_i/H_v`` (:func:`~observer.estimation.frontend.
    apply_relative`), against the waveform itself seen through ``current``'s front end (or
    ``voltage``'s), both over the intervals read ``shift`` periods late.

    The place indexes the jump against the samples, which the delay does not move: what the
    interpolant misses depends on where the samples caught the jump. (Tabulated at no delay
    and read at the place less it, the miss was that of a sampling that never happened: an
    RC field voltage beside a Butterworth current, read -0.28 periods late, put the
    traction motor's Rf +1.1 % off at 5 std.)"""
    fs = 1.0 / dt

    def poles(fe: FrontEnd) -> tuple[np.ndarray, np.ndarray]:
        return poles_residues(filter_sections(fe.filter, fe.order, fe.cutoff_at(fs)), dt)

    pv, rv = poles(voltage)
    relative = current is not None and current != voltage
    target = current if relative and current is not None else voltage
    pt, rt = poles(target)
    # A jump fitted at t0 in the voltage's samples (taken d_v late) is seen by the current's
    # channel (taken d_i late) at t0 + (d_v - d_i) on the nominal grid.
    lag = (voltage.delay_s - target.delay_s) / dt
    n = 2 * _TABLE_SAMPLES
    k = np.arange(-_TABLE_SAMPLES, _TABLE_SAMPLES, dtype=float)
    out = np.zeros((2, FRACTIONS, 2 * HALF_WIDTH + 1, 3))
    rows = slice(_TABLE_SAMPLES - HALF_WIDTH, _TABLE_SAMPLES + HALF_WIDTH + 1)
    for kind in (0, 1):
        for q, frac in enumerate(np.linspace(0.0, 1.0, FRACTIONS)):
            samples = _step_values(pv, rv, k - frac, bool(kind))
            if relative and current is not None:
                samples = apply_relative(samples, dt, voltage, current)
            seen = smooth_moments(samples, Segments.whole(n), shift)[rows]
            out[kind, q] = _exact_moments(pt, rt, frac + lag - shift, bool(kind)) - seen
    out.flags.writeable = False
    return out


@njit(cache=True, nogil=True)
def _add_corrections(jumps: np.ndarray, table: np.ndarray, weight: float, mu: np.ndarray) -> None:
    """Add ``weight`` times each jump's tabulated miss to ``mu`` in place."""
    n_int = mu.shape[0]
    nq = table.shape[1]
    half = (table.shape[2] - 1) // 2
    for j in range(jumps.shape[0]):
        t = jumps[j, 0]
        k0 = int(math.floor(t))
        q = (t - k0) * (nq - 1)
        q0 = min(int(q), nq - 2)
        a = q - q0
        for row in range(table.shape[2]):
            i = k0 - half + row
            if i < 0 or i >= n_int:
                continue
            for c in range(3):
                step = (1.0 - a) * table[0, q0, row, c] + a * table[0, q0 + 1, row, c]
                ramp = (1.0 - a) * table[1, q0, row, c] + a * table[1, q0 + 1, row, c]
                mu[i, c] += weight * (jumps[j, 1] * step + jumps[j, 2] * ramp)


@dataclass(frozen=True)
class JumpReconstruction:
    """A window's fitted jumps and the front ends that turn them into moment corrections.

    Attributes
    ----------
    jumps : (m, 3) array
        Instant (samples), value jump (V) and slope jump (V per sample) of each jump.
    voltage, current : FrontEnd
        The voltage's filter and the current's front end (None: the voltage's), whose
        :func:`correction_table` the corrections are read from.
    dt : float
        Sample period (s).
    """

    jumps: np.ndarray
    voltage: FrontEnd
    current: FrontEnd | None
    dt: float

    def correct(self, mu: np.ndarray, shift: float) -> np.ndarray:
        """``mu`` (interval moments read ``shift`` periods late) with the jumps put back:
        the tables at the two delays of :data:`SHIFT_STEP` about ``shift``, interpolated."""
        out = np.array(mu, dtype=np.float64)
        below = math.floor(shift / SHIFT_STEP + 1e-9)
        a = shift / SHIFT_STEP - below
        for step, weight in ((below, 1.0 - a), (below + 1, a)):
            if weight > 1e-9:
                table = correction_table(self.voltage, self.current, self.dt, step * SHIFT_STEP)
                _add_corrections(self.jumps, table, float(weight), out)
        return out


def identified_front_end(name: str | None) -> FrontEnd | None:
    """The :class:`FrontEnd` of an identified candidate (``butter2@0.250``), None for none."""
    if not name or name == "none":
        return None
    kind, order, frac = parse_candidate(name)
    return FrontEnd(kind, order, cutoff_per_fs=frac)


def reconstruction(
    raw_voltage: np.ndarray,
    dt: float,
    starts: np.ndarray,
    voltage: FrontEnd | None,
    current: FrontEnd | None,
) -> JumpReconstruction | None:
    """The :class:`JumpReconstruction` of a window whose voltage was filtered by ``voltage``
    (its jumps' first flagged intervals ``starts``); None where there is nothing to put back
    (no filter, an averaging channel, too few of its jumps fitted: :data:`MIN_FITTED_SHARE`)."""
    if voltage is None or voltage.filter == "none" or voltage.order == 0:
        return None
    if voltage.averaging or (current is not None and current.averaging):
        return None
    sections = filter_sections(voltage.filter, voltage.order, voltage.cutoff_at(1.0 / dt))
    jumps = fit_jumps(raw_voltage, dt, sections, starts)
    if jumps.shape[0] == 0 or jumps.shape[0] < MIN_FITTED_SHARE * starts.shape[0]:
        return None
    return JumpReconstruction(jumps, voltage, current, dt)
