"""Single-producer, single-consumer ring buffer of samples.

The source thread writes blocks; the observer thread copies out the samples it
has not seen yet (for the log) and windows of the latest samples (for the
estimators). Storage is preallocated once: a write is a few slice copies into
the existing arrays, never an allocation per sample.

Synchronisation relies on one counter, :attr:`RingBuffer.written`, the number
of samples ever written, which the producer advances *after* copying a block
in. A reader copies first and checks afterwards that the producer has not
lapped the region it copied (a seqlock): if it did, the copy is discarded and
the samples lost are counted as an overrun. Nothing is ever lost silently.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from drivers.base import CHANNELS, AdcScale, SampleBlock


@dataclass(frozen=True)
class Window:
    """Samples copied out of the ring.

    Attributes
    ----------
    t_ns : (n,) int64
        Sample times (ns).
    signals : dict of channel -> (n,) float64
    arrival_ns : (n,) int64
        Host monotonic time at which each sample was written to the ring.
    start : int
        Sequence number (0-based count of samples ever written) of the first sample.
    scales : mapping of channel -> AdcScale
        The ADC scales of the newest block written (see :class:`drivers.base.SampleBlock`);
        a consumer recovering counts checks that they reproduce the values.
    """

    t_ns: np.ndarray
    signals: dict[str, np.ndarray]
    arrival_ns: np.ndarray
    start: int
    scales: Mapping[str, AdcScale] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


class RingBuffer:
    """Preallocated ring of ``capacity`` samples of ``channels``.

    Parameters
    ----------
    capacity : int
        Samples held; a consumer that falls further behind than this loses samples
        (counted in :attr:`overrun_samples`).
    channels : tuple of str
        Channels stored (subset of :data:`drivers.base.CHANNELS`); a block lacking
        one of them stores NaN there.
    """

    def __init__(self, capacity: int, channels: tuple[str, ...] = CHANNELS) -> None:
        if capacity < 2:
            raise ValueError(f"capacity must be >= 2 samples, got {capacity}")
        unknown = [c for c in channels if c not in CHANNELS]
        if unknown or not channels:
            raise ValueError(f"channels must be a non-empty subset of {CHANNELS}, got {channels}")
        self.capacity = int(capacity)
        self.channels = tuple(channels)
        self._t = np.zeros(capacity, dtype=np.int64)
        self._arrival = np.zeros(capacity, dtype=np.int64)
        self._data = np.full((len(channels), capacity), np.nan)
        self._written = 0  # advanced by the producer only, after the copy
        self._reserved = 0  # advanced by the producer only, before the copy
        self._read = 0  # advanced by the consumer only
        self.overruns = 0  # times the consumer was lapped
        self.overrun_samples = 0  # samples the consumer never saw
        self.blocks_written = 0
        self.scales: Mapping[str, AdcScale] = MappingProxyType({})
        self._cond = threading.Condition()

    @property
    def written(self) -> int:
        """Samples ever written."""
        return self._written

    @property
    def last_t_ns(self) -> int | None:
        """Time of the newest sample, or None if empty."""
        n = self._written
        return None if n == 0 else int(self._t[(n - 1) % self.capacity])

    # ----------------------------------------------------------------- producer

    def write(self, block: SampleBlock) -> None:
        """Append a block (producer thread only). Blocks longer than the ring keep their tail."""
        n = len(block)
        if n == 0:
            return
        skip = max(0, n - self.capacity)
        if skip:  # only the tail can be held; the head is lost to every consumer
            self.overruns += 1
            self.overrun_samples += skip
        now = time.monotonic_ns()
        start = self._written + skip
        pos = start % self.capacity
        count = n - skip
        first = min(count, self.capacity - pos)
        rest = count - first
        self._reserved = start + count  # readers of slots about to be overwritten retry
        self._t[pos : pos + first] = block.t_ns[skip : skip + first]
        self._t[:rest] = block.t_ns[skip + first :]
        self._arrival[pos : pos + first] = now
        self._arrival[:rest] = now
        for row, name in enumerate(self.channels):
            values = block.signals.get(name)
            if values is None:
                self._data[row, pos : pos + first] = np.nan
                self._data[row, :rest] = np.nan
            else:
                self._data[row, pos : pos + first] = values[skip : skip + first]
                self._data[row, :rest] = values[skip + first :]
        self.scales = block.scales
        with self._cond:
            self._written = start + count
            self.blocks_written += 1
            self._cond.notify_all()

    # ----------------------------------------------------------------- consumer

    def wait_for(self, written: int, timeout: float | None) -> bool:
        """Block until at least ``written`` samples were ever written, or timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._written >= written, timeout)

    def wait_for_time(self, t_ns: int, timeout: float | None) -> bool:
        """Block until a sample at or after ``t_ns`` was written, or timeout."""

        def reached() -> bool:
            last = self.last_t_ns
            return last is not None and last >= t_ns

        with self._cond:
            return self._cond.wait_for(reached, timeout)

    def notify(self) -> None:
        """Wake waiting consumers (e.g. at shutdown)."""
        with self._cond:
            self._cond.notify_all()

    def _copy(self, start: int, stop: int) -> Window | None:
        idx = np.arange(start, stop) % self.capacity
        window = Window(
            t_ns=self._t[idx],
            signals={name: self._data[row, idx] for row, name in enumerate(self.channels)},
            arrival_ns=self._arrival[idx],
            start=start,
            scales=self.scales,
        )
        # Seqlock check: the producer may have overwritten [start, ...) while we
        # copied, or be overwriting it now (slots up to _reserved are in play).
        if self._reserved - self.capacity > start:
            return None
        return window

    def read_new(self, max_samples: int | None = None) -> Window | None:
        """Samples written since the last ``read_new`` (consumer thread only).

        Samples the producer overwrote before they were read are skipped and
        counted in :attr:`overruns` / :attr:`overrun_samples`.
        """
        for _ in range(3):
            written = self._written
            if self._read < written - self.capacity:
                lost = written - self.capacity - self._read
                self.overruns += 1
                self.overrun_samples += lost
                self._read += lost
            stop = written if max_samples is None else min(written, self._read + max_samples)
            if stop <= self._read:
                return None
            window = self._copy(self._read, stop)
            if window is not None:
                self._read = stop
                return window
        return None

    def latest(self, n: int) -> Window | None:
        """A copy of the last ``n`` samples (fewer if fewer were written), or None if empty."""
        for _ in range(3):
            written = self._written
            start = max(0, written - min(n, self.capacity - 1))
            if written == start:
                return None
            window = self._copy(start, written)
            if window is not None:
                return window
        return None

    def between(self, t0_ns: int, t1_ns: int) -> Window | None:
        """A copy of the samples with ``t0_ns < t <= t1_ns`` still held, or None.

        Assumes times increase within the held samples (a jump back is found by
        the caller's checks on the copy).
        """
        for _ in range(3):
            written = self._written
            oldest = max(0, written - self.capacity + 1)
            if written == oldest:
                return None
            held = np.arange(oldest, written) % self.capacity
            times = self._t[held]
            lo = int(np.searchsorted(times, t0_ns, side="right"))
            hi = int(np.searchsorted(times, t1_ns, side="right"))
            if hi <= lo:
                return None
            window = self._copy(oldest + lo, oldest + hi)
            if window is not None:
                return window
        return None

    def stats(self) -> dict[str, int]:
        """Counters for health reports."""
        return {
            "capacity": self.capacity,
            "written": self._written,
            "blocks": self.blocks_written,
            "overruns": self.overruns,
            "overrun_samples": self.overrun_samples,
        }
