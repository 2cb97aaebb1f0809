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
follow; the test's cost is a few array operations per window for all onsets.

A small class; the tracker (:mod:`observer.service.tracker`) feeds it the
filter's transitions and updates, and decides what a confirmed change does to
its state.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    Call :meth:`predict` with every transition of the filter, :meth:`open` once
    per window (a step may have happened since the last), then :meth:`observe`
    for a window whose innovation the test takes, with the gain if the filter
    took the window in.
    """

    def __init__(
        self, shift: float, threshold: float, *, horizon_s: float, window_s: float
    ) -> None:
        if not (shift > 0 and threshold > 0 and horizon_s > 0 and window_s > 0):
            raise ValueError(
                "shift, threshold, horizon_s and window_s must be > 0, got "
                f"{shift}, {threshold}, {horizon_s}, {window_s}"
            )
        self.shift = shift
        self.threshold = threshold
        self.horizon_ns = int(round(horizon_s * 1e9))
        self.window_ns = int(round(window_s * 1e9))
        self.level = 0.0  # the largest ratio as a fraction of the threshold (0: no evidence)
        self.reset()

    def reset(self) -> None:
        """Forget every onset (after a change, or when the state is reset)."""
        self._onset = np.empty(0, dtype=np.int64)
        self._mu = np.empty((0, 0))
        self._eta = np.empty((0, 0))
        self._d = np.empty(0)
        self._c = np.empty(0)
        self.level = 0.0

    def predict(self, transition: np.ndarray) -> None:
        """The filter's prediction ``x' = F x`` (linearised): both effects move with it."""
        if self._onset.size:
            self._mu = self._mu @ transition.T
            self._eta = self._eta @ transition.T

    def open(self, onset_ns: int, direction: np.ndarray, now_ns: int) -> None:
        """Test a step at ``onset_ns`` too: ``direction`` is the state's change per unit
        step of the level; onsets before ``now_ns - horizon`` are dropped."""
        keep = self._onset >= now_ns - self.horizon_ns
        if self._onset.size and self._mu.shape[1] != direction.size:
            keep[:] = False  # the state's shape changed: a new filter
        self._onset = np.append(self._onset[keep], np.int64(onset_ns))
        dim = direction.size
        self._mu = np.vstack([self._mu[keep].reshape(-1, dim), direction[None, :]])
        self._eta = np.vstack([self._eta[keep].reshape(-1, dim), np.zeros((1, dim))])
        self._d = np.append(self._d[keep], 0.0)
        self._c = np.append(self._c[keep], 0.0)

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
        if not self._onset.size:
            return None
        share = np.clip((t_ns - self._onset) / self.window_ns, 0.0, 1.0)
        rho = share * (self._mu @ row) - self._eta @ row
        self._d += rho * (innovation / variance)
        self._c += rho * rho / variance
        if gain is not None:
            self._eta += np.outer(rho, gain)
        m = self.shift
        c = np.maximum(self._c, 1e-300)
        d = self._d
        size = d / c
        ratio = np.where(np.abs(size) >= m, 0.5 * d * size, m * np.abs(d) - 0.5 * m * m * c)
        best = int(np.argmax(ratio))
        self.level = max(float(ratio[best]), 0.0) / self.threshold
        if ratio[best] < self.threshold:
            return None
        direction = 1 if d[best] > 0 else -1
        step = direction * max(abs(float(size[best])), m)
        return Alarm(direction, int(self._onset[best]), step)
