"""Change detection on the tracker's innovations: a generalised likelihood ratio for a step.

A window whose fit disagrees with the tracked state is either noise, a slow
drift the tracker follows, or a real change (a loose connection adds 3 % to
``Ra`` at once; a field fault takes 5 % off ``K``). The tracker is a Kalman
filter, so a step does not stay in its innovations: every window taken in
moves the state towards the new level (and, for a resistance tracked with a
rate, bends the rate), and the innovations after a step shrink window by
window. A test that expects a constant shift in them (Page's CUSUM) then
gathers evidence ever more slowly, while the state creeps after the step as a
drift no resistance can have. Willsky and Jones' generalised likelihood ratio
("A generalized likelihood ratio approach to the detection and estimation of
jumps in linear systems", IEEE TAC 21(1), 1976) follows the step *through the
filter*: for a unit step in the level at time ``k``

* ``mu`` is its effect on the true state (propagated by the transition),
* ``eta`` its effect on the filter's estimate (propagated by the transition,
  and moved by the gain at every update),
* a window ending at ``t`` shows ``rho = f * (h . mu) - h . eta`` of it in its
  innovation, ``h`` the observation row and ``f`` the share of the window's
  samples after ``k`` (a window's fit is an average over its samples: windows
  sliding across a step show a growing share of it).

With ``nu`` the innovations and ``S`` their variances, ``d = sum(rho nu / S)``
and ``C = sum(rho^2 / S)`` give the step's maximum-likelihood size ``d / C``
and its log-likelihood ratio against "no step", ``d^2 / (2 C)``. Only steps of
at least the smallest change worth announcing ``m`` (log units) are tested:
where ``|d / C| < m`` the ratio is the one at ``+-m``, ``m |d| - m^2 C / 2``.
The largest ratio over the onsets of the last ``horizon`` seconds above
``threshold`` (log-likelihood units: ``e^threshold`` to one odds) confirms a
change, and its onset dates it. Changes below ``m`` are left to the tracker to
follow; one compiled pass a window does the work for all onsets.

A small class; the tracker (:mod:`observer.service.tracker`) feeds it the
filter's transitions and updates, and decides what a confirmed change does to
its state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@dataclass(frozen=True)
class Alarm:
    """A change confirmed by :class:`StepGlr`.

    Attributes
    ----------
    direction : int
        +1: the parameter rose; -1: it fell.
    started_ns : int
        When the change happened (ns): the most likely onset, within a hop.
    size : float
        The step's maximum-likelihood size (log units, at least the smallest
        change tested).
    """

    direction: int
    started_ns: int
    size: float = 0.0


class StepGlr:
    """Generalised likelihood ratio of a step in a Kalman-tracked level, over recent onsets.

    Parameters
    ----------
    shift : float
        The smallest change worth announcing (log units, > 0).
    threshold : float
        Log-likelihood ratio that confirms it (> 0).
    horizon_s : float
        Onsets older than this (s) are no longer tested: a step the test has not
        confirmed by then is left to the tracker.
    window_s : float
        Length of the windows whose fits are observed (s).
    hop_s : float
        Time between windows (s): with the horizon, how many onsets are kept.

    Call :meth:`predict` with every transition of the filter, :meth:`open` once
    per window (a step may have happened since the last), then :meth:`observe`
    for a window whose innovation the test takes, with the gain if the filter
    took the window in. The onsets live in a ring of fixed size and one compiled
    pass does each window's work for all of them (tens of microseconds a window
    for every parameter).
    """

    def __init__(
        self, shift: float, threshold: float, *, horizon_s: float, window_s: float, hop_s: float
    ) -> None:
        if not (shift > 0 and threshold > 0 and horizon_s > 0 and window_s > 0 and hop_s > 0):
            raise ValueError(
                "shift, threshold, horizon_s, window_s and hop_s must be > 0, got "
                f"{shift}, {threshold}, {horizon_s}, {window_s}, {hop_s}"
            )
        self.shift = shift
        self.threshold = threshold
        self.horizon_ns = int(round(horizon_s * 1e9))
        self.window_ns = int(round(window_s * 1e9))
        self.capacity = math.ceil(horizon_s / hop_s - 1e-9) + 1
        self.level = 0.0  # the largest ratio as a fraction of the threshold (0: no evidence)
        self._dim = 0
        self.reset()

    def reset(self) -> None:
        """Forget every onset (after a change, or when the state is reset)."""
        self._count = 0  # onsets kept (the ring's first _count slots once filled)
        self._next = 0  # the slot the next onset takes
        self._onset = np.zeros(self.capacity, dtype=np.int64)
        self._mu = np.zeros((self.capacity, max(self._dim, 1)))
        self._eta = np.zeros_like(self._mu)
        self._d = np.zeros(self.capacity)
        self._c = np.zeros(self.capacity)
        self.level = 0.0

    def predict(self, transition: np.ndarray) -> None:
        """The filter's prediction ``x' = F x`` (linearised): both effects move with it."""
        if self._count and transition.shape == (self._dim, self._dim):
            _glr_predict(self._mu, self._eta, self._count, np.ascontiguousarray(transition, float))

    def open(self, onset_ns: int, direction: np.ndarray) -> None:
        """Test a step at ``onset_ns`` too: ``direction`` is the state's change per unit
        step of the level (onsets beyond the horizon are no longer tested in
        :meth:`observe`; the ring keeps the latest)."""
        if direction.size != self._dim:  # a new filter
            self._dim = direction.size
            self.reset()
        k = self._next
        self._onset[k] = onset_ns
        self._mu[k] = direction
        self._eta[k] = 0.0
        self._d[k] = 0.0
        self._c[k] = 0.0
        self._next = (k + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)

    def observe(
        self,
        t_ns: int,
        row: np.ndarray,
        innovation: float,
        variance: float,
        gain: np.ndarray | None,
    ) -> Alarm | None:
        """Take one window's innovation (log units) and its variance; ``gain``: the
        filter's gain if it updated on it (None: it did not). An :class:`Alarm`
        once a step is confirmed."""
        if not self._count:
            return None
        best, ratio = _glr_observe(
            self._onset, self._mu, self._eta, self._d, self._c, self._count,
            t_ns, self.window_ns, t_ns - self.horizon_ns,
            np.ascontiguousarray(row, float), innovation, variance,
            np.zeros(self._dim) if gain is None else np.ascontiguousarray(gain, float),
            gain is not None, self.shift,
        )  # fmt: skip
        self.level = max(ratio, 0.0) / self.threshold
        if best < 0 or ratio < self.threshold:
            return None
        d = float(self._d[best])
        direction = 1 if d > 0 else -1
        return Alarm(
            direction, int(self._onset[best]), direction * max(abs(d / self._c[best]), self.shift)
        )


@njit(nogil=True, cache=True)
def _glr_predict(mu: np.ndarray, eta: np.ndarray, count: int, transition: np.ndarray) -> None:
    """``mu = mu F'``, ``eta = eta F'`` over the first ``count`` rows, in place."""
    dim = mu.shape[1]
    a = np.empty(dim)
    b = np.empty(dim)
    for k in range(count):
        for i in range(dim):
            sa = 0.0
            sb = 0.0
            for j in range(dim):
                sa += transition[i, j] * mu[k, j]
                sb += transition[i, j] * eta[k, j]
            a[i] = sa
            b[i] = sb
        for i in range(dim):
            mu[k, i] = a[i]
            eta[k, i] = b[i]


@njit(nogil=True, cache=True)
def _glr_observe(
    onset: np.ndarray,
    mu: np.ndarray,
    eta: np.ndarray,
    d: np.ndarray,
    c: np.ndarray,
    count: int,
    t_ns: int,
    window_ns: int,
    oldest_ns: int,
    row: np.ndarray,
    innovation: float,
    variance: float,
    gain: np.ndarray,
    updated: bool,
    shift: float,
) -> tuple[int, float]:
    """One window for every onset: each one's signature ``rho`` and sums ``d``, ``C``
    (and ``eta`` moved by the gain if the filter updated); the onset within the
    horizon with the largest ratio, and that ratio (-1, -inf: none)."""
    dim = mu.shape[1]
    best = -1
    best_ratio = -np.inf
    for k in range(count):
        share = min(max((t_ns - onset[k]) / window_ns, 0.0), 1.0)
        seen = 0.0
        taken = 0.0
        for j in range(dim):
            seen += row[j] * mu[k, j]
            taken += row[j] * eta[k, j]
        rho = share * seen - taken
        d[k] += rho * (innovation / variance)
        c[k] += rho * rho / variance
        if updated:
            for j in range(dim):
                eta[k, j] += rho * gain[j]
        if onset[k] < oldest_ns or c[k] <= 0.0:
            continue
        size = d[k] / c[k]
        if abs(size) >= shift:
            ratio = 0.5 * d[k] * size
        else:
            ratio = shift * abs(d[k]) - 0.5 * shift * shift * c[k]
        if ratio > best_ratio:
            best_ratio = ratio
            best = k
    return best, best_ratio
