"""Change detection on the tracker's innovations: a two-sided CUSUM of log-likelihood ratios.

A window whose fit disagrees with the tracked state is either noise, a slow
drift the tracker follows, or a real change (a loose connection adds 3 % to
``Ra`` at once; a field fault takes 5 % off ``K``). Each parameter has a
*smallest change worth announcing* ``m`` (relative). For every window with
evidence the log-likelihood ratio of "the parameter moved by ``+m`` (or
``-m``)" against "it did not" is, for a Gaussian innovation ``nu`` with
variance ``S`` (both in log units),

    s = (m / S) * (+-nu - m / 2)

and Page's CUSUM ``g = max(0, g + s)`` accumulates it; ``g`` above
``threshold`` (log-likelihood units: ``e^threshold`` to one odds) confirms a
change. Innovations of windows that are weak (large ``S``) or smaller than
``m / 2`` add nothing or take away, so changes below ``m`` are left to the
tracker to follow and weak, biased windows cannot add up to an alarm. The
run's start (the last window at which ``g`` was zero) dates the change.

Pure functions and a small class; the tracker (:mod:`observer.service.tracker`)
decides what a confirmed change does to its state.
"""

from __future__ import annotations

from dataclasses import dataclass


def llr_increment(innovation: float, variance: float, shift: float) -> float:
    """Log-likelihood ratio of a shift of ``shift`` in the mean of one Gaussian innovation.

    Parameters
    ----------
    innovation : float
        Window fit minus the tracked prediction (log units).
    variance : float
        Variance of the innovation (log units squared), > 0.
    shift : float
        The shift tested (log units, either sign).
    """
    return shift / variance * (innovation - 0.5 * shift)


@dataclass(frozen=True)
class Alarm:
    """A change confirmed by :class:`Cusum`.

    Attributes
    ----------
    direction : int
        +1: the parameter rose; -1: it fell.
    started_ns : int
        Time (ns) of the first window of the run that confirmed it: the change
        happened within the hop before that window's end.
    """

    direction: int
    started_ns: int


class Cusum:
    """Two-sided CUSUM of :func:`llr_increment` for a shift of ``+-shift``.

    Parameters
    ----------
    shift : float
        The smallest change worth announcing (log units, > 0).
    threshold : float
        Log-likelihood ratio that confirms it (> 0).
    """

    def __init__(self, shift: float, threshold: float) -> None:
        if not (shift > 0 and threshold > 0):
            raise ValueError(f"shift and threshold must be > 0, got {shift}, {threshold}")
        self.shift = shift
        self.threshold = threshold
        self.up = 0.0
        self.down = 0.0
        self._up_start: int | None = None
        self._down_start: int | None = None

    def reset(self) -> None:
        """Forget the evidence so far (after a change, or when the state is reset)."""
        self.up = self.down = 0.0
        self._up_start = self._down_start = None

    @property
    def level(self) -> float:
        """The larger of the two sums, as a fraction of the threshold (0: no evidence)."""
        return max(self.up, self.down) / self.threshold

    def update(self, innovation: float, variance: float, t_ns: int) -> Alarm | None:
        """Add one window's innovation; an :class:`Alarm` once a change is confirmed."""
        up = self.up + llr_increment(innovation, variance, self.shift)
        down = self.down + llr_increment(innovation, variance, -self.shift)
        if up <= 0.0:
            up, self._up_start = 0.0, None
        elif self._up_start is None:
            self._up_start = t_ns
        if down <= 0.0:
            down, self._down_start = 0.0, None
        elif self._down_start is None:
            self._down_start = t_ns
        self.up, self.down = up, down
        if up >= self.threshold and up >= down:
            assert self._up_start is not None
            return Alarm(+1, self._up_start)
        if down >= self.threshold:
            assert self._down_start is not None
            return Alarm(-1, self._down_start)
        return None
