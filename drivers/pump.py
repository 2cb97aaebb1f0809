"""What the hardware adapters share: a pump thread, a bounded buffer, reconnects, device clocks.

A hardware adapter (:class:`PumpedSource`) reads its device on a pump thread
into a bounded buffer of samples, so the device is drained at its own pace
whatever the consumer does. When the consumer falls behind and the buffer is
full, the *oldest* samples are discarded and counted (``dropped`` and
``overrun_samples`` in the health counters): overruns are visible, never
hidden. ``received_samples`` counts what the pump took from the device:
``received_samples == samples + overrun_samples + (still buffered)``. The
pump thread never dies silently: every exception is counted in ``errors``,
logged, and answered by closing the device and reconnecting with exponential
backoff (counted in ``reconnects``).

Timestamps. Where the protocol carries a device clock, :class:`DeviceClock`
unwraps it and places it on the host monotonic time line: the first sample of
a connection is anchored at the host time it was received, later samples
follow the *device* clock (no host scheduling jitter, but the device
oscillator's drift against the host, typically < 100 ppm, accumulates until
the next re-anchoring at a reconnect or a clock jump). Sources without a
device clock stamp samples with the host monotonic clock when they arrive
(jitter of the host's scheduling and of the transport, typically 0.1-1 ms).
"""

from __future__ import annotations

import abc
import dataclasses
import logging
import threading
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np

from drivers.base import AdcScale, SampleBlock, Source, SourceClosed

log = logging.getLogger(__name__)


class DeviceLost(Exception):
    """The device went away (port closed, peer disconnected, silent too long)."""


@dataclass(frozen=True)
class PumpOptions:
    """Options every pumped source has: its buffer, staleness and reconnect backoff.

    A source's ``Options`` dataclass derives from this, so the four keys read the
    same in every ``[source.options]`` table and :meth:`PumpedSource.__init__` takes
    them from one place.
    """

    buffer_samples: int = dataclasses.field(default=65536, metadata={"min": 1})
    stale_timeout_s: float = dataclasses.field(default=2.0, metadata={"min": 0.0})
    reconnect_initial_s: float = dataclasses.field(default=0.05, metadata={"min": 0.001})
    reconnect_max_s: float = dataclasses.field(default=2.0, metadata={"min": 0.001})

    def pump_settings(self) -> dict[str, Any]:
        """Keyword arguments of :class:`PumpedSource` for these options."""
        return {
            "buffer_samples": self.buffer_samples,
            "backoff": Backoff(self.reconnect_initial_s, self.reconnect_max_s),
            "stale_timeout_s": self.stale_timeout_s,
        }


@dataclass
class Backoff:
    """Exponential backoff between reconnect attempts.

    Parameters
    ----------
    initial_s : float
        First delay (s).
    maximum_s : float
        Upper bound of the delay (s).
    factor : float
        Growth per failed attempt.
    """

    initial_s: float = 0.05
    maximum_s: float = 2.0
    factor: float = 2.0

    def __post_init__(self) -> None:
        if not (0 < self.initial_s <= self.maximum_s) or self.factor < 1:
            raise ValueError(
                "backoff needs 0 < initial_s <= maximum_s and factor >= 1, got "
                f"{self.initial_s}, {self.maximum_s}, {self.factor}"
            )
        self._next = self.initial_s

    def next_delay(self) -> float:
        """The delay before the next attempt (s); grows each call up to ``maximum_s``."""
        delay = self._next
        self._next = min(self.maximum_s, self._next * self.factor)
        return delay

    def reset(self) -> None:
        """Back to ``initial_s`` (after a successful connection)."""
        self._next = self.initial_s


class DeviceClock:
    """Unwrap a wrapping device counter and map it to host-monotonic nanoseconds.

    Parameters
    ----------
    wrap : int
        The counter wraps at this value (``2**32`` for a 32-bit counter).
    tick_ns : int
        Nanoseconds per counter tick (1000 for a microsecond counter).
    max_step_ns : int
        A step between consecutive samples larger than this, or backwards, is
        taken as a device restart: the clock is re-anchored to the host time.
    """

    def __init__(self, wrap: int, tick_ns: int, max_step_ns: int) -> None:
        self.wrap = int(wrap)
        self.tick_ns = int(tick_ns)
        self.max_step_ns = int(max_step_ns)
        self.reanchors = 0
        self._last_raw: int | None = None
        self._last_ns = -(2**62)

    def reset(self) -> None:
        """Forget the device epoch (a new connection): the next sample re-anchors."""
        self._last_raw = None

    def convert(self, raw: np.ndarray, host_ns: int) -> np.ndarray:
        """Sample times (int64 ns, strictly increasing) of device counter values ``raw``.

        ``host_ns`` is the host monotonic time at which the last of them was received.
        """
        raw = np.asarray(raw, dtype=np.int64) % self.wrap
        n = raw.shape[0]
        if n == 0:
            return np.empty(0, dtype=np.int64)
        previous = np.empty(n, dtype=np.int64)
        previous[0] = -1 if self._last_raw is None else self._last_raw
        previous[1:] = raw[:-1]
        steps = ((raw - previous) % self.wrap) * self.tick_ns
        restart = (steps <= 0) | (steps > self.max_step_ns)
        restart[0] |= self._last_raw is None
        steps[restart] = 0
        out = np.empty(n, dtype=np.int64)
        edges = [0, *np.flatnonzero(restart).tolist(), n]
        edges = sorted(set(edges))
        last = self._last_ns
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            offsets = np.cumsum(steps[a:b])
            if restart[a]:
                self.reanchors += 1
                # The last sample of the batch arrived at host_ns; an earlier
                # segment (a restart inside the batch) just follows the last time.
                base = host_ns - int(offsets[-1]) if b == n else last + 1
                base = max(base, last + 1)  # never back in time, even across a restart
            else:
                base = last
            out[a:b] = base + offsets
            last = int(out[b - 1])
        self._last_raw = int(raw[-1])
        self._last_ns = last
        return out


class PumpedSource(Source):
    """A source whose device is drained by a pump thread into a bounded buffer.

    Subclasses implement :meth:`_connect`, :meth:`_disconnect` and
    :meth:`_receive`. ``_receive`` raising anything means the connection is
    bad: it is closed, the error counted and logged, and the pump reconnects
    after a backoff delay.

    Parameters
    ----------
    buffer_samples : int
        Capacity of the buffer between pump and consumer (samples).
    backoff : Backoff
        Delays between reconnect attempts.
    stale_timeout_s : float
        A connected device that delivers no sample for this long is taken as
        gone (0 disables): it is closed and reconnected.
    """

    #: Extra health counters, present (as 0) from the start.
    counters: tuple[str, ...] = ("received_samples", "overrun_samples")

    #: ADC scales of the channels ``_receive`` computes as ``offset + lsb * count``
    #: (exactly that float64 formula), handed on with every block.
    scales: Mapping[str, AdcScale] = MappingProxyType({})

    def __init__(
        self,
        *,
        buffer_samples: int = 65536,
        backoff: Backoff | None = None,
        stale_timeout_s: float = 0.0,
    ) -> None:
        super().__init__()
        self._health.extra.update(dict.fromkeys(self.counters, 0))
        if buffer_samples < 1:
            raise ValueError(f"buffer_samples must be >= 1, got {buffer_samples}")
        self.buffer_samples = int(buffer_samples)
        self.backoff = backoff if backoff is not None else Backoff()
        self.stale_timeout_s = float(stale_timeout_s)
        self._chunks: deque[tuple[np.ndarray, dict[str, np.ndarray]]] = deque()
        self._buffered = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._device_connected = False
        self._connected_once = threading.Event()

    # -- backend hooks ---------------------------------------------------------

    @abc.abstractmethod
    def _connect(self) -> None:
        """Open the device; raise on failure."""

    @abc.abstractmethod
    def _disconnect(self) -> None:
        """Close the device; must not raise and must tolerate a half-open device."""

    @abc.abstractmethod
    def _receive(self, timeout: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        """Samples that arrived within ``timeout`` seconds: ``(t_ns, {channel: values})``."""

    # -- Source hooks ------------------------------------------------------------

    def _open(self) -> None:
        self._thread = threading.Thread(target=self._pump, name=f"{self.name}-pump", daemon=True)
        self._thread.start()

    def _close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():  # pragma: no cover - a driver call that never returns
                log.warning("%s pump thread did not stop within 5 s", self.name)

    def _read_block(self, timeout: float | None) -> SampleBlock | None:
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._chunks:
                if self._closed:
                    raise SourceClosed(f"{self.name} source is closed")
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                self._cond.wait(remaining)
            chunks = list(self._chunks)
            self._chunks.clear()
            self._buffered = 0
        t = np.concatenate([c[0] for c in chunks])
        names = chunks[0][1].keys()
        signals = {name: np.concatenate([c[1][name] for c in chunks]) for name in names}
        return SampleBlock(t, signals, {c: s for c, s in self.scales.items() if c in signals})

    def health(self) -> dict[str, Any]:
        """Health counters; ``connected`` is the device's state as the pump sees it."""
        out = super().health()
        out["connected"] = bool(self._device_connected and not self._closed)
        return out

    @property
    def buffered(self) -> int:
        """Samples waiting in the buffer for the consumer."""
        with self._cond:
            return self._buffered

    def wait_connected(self, timeout: float) -> bool:
        """Block until the device was connected at least once (True) or ``timeout`` passed."""
        return self._connected_once.wait(timeout)

    def _add(self, **deltas: int) -> None:
        """Add to health counters, named fields or extras alike, under the lock."""
        with self._lock:
            h = self._health
            for key, d in deltas.items():
                if hasattr(h, key):
                    setattr(h, key, getattr(h, key) + d)
                else:
                    h.extra[key] = h.extra.get(key, 0) + d

    # -- the pump ------------------------------------------------------------------

    def _push(self, t_ns: np.ndarray, signals: Mapping[str, np.ndarray]) -> None:
        n = int(t_ns.shape[0])
        if n == 0:
            return
        overrun = 0
        self._add(received_samples=n)
        with self._cond:
            self._chunks.append((t_ns, dict(signals)))
            self._buffered += n
            while self._buffered > self.buffer_samples:
                excess = self._buffered - self.buffer_samples
                t0, s0 = self._chunks[0]
                if t0.shape[0] <= excess:
                    self._chunks.popleft()
                    overrun += t0.shape[0]
                    self._buffered -= t0.shape[0]
                else:
                    self._chunks[0] = (t0[excess:], {k: v[excess:] for k, v in s0.items()})
                    overrun += excess
                    self._buffered -= excess
            self._cond.notify_all()
        if overrun:
            self._add(dropped=overrun, overrun_samples=overrun)

    def _pump(self) -> None:
        ever_connected = False
        while not self._stop.is_set():
            if not self._device_connected:
                try:
                    self._connect()
                except Exception as exc:
                    self._count(error=f"connect: {exc}")
                    log.warning("%s: cannot connect: %s", self.name, exc)
                    self._safe_disconnect()
                    self._stop.wait(self.backoff.next_delay())
                    continue
                if ever_connected:
                    self._count(reconnects=1)
                    log.info("%s: reconnected", self.name)
                ever_connected = True
                self._device_connected = True
                self._connected_once.set()
                last_data = time.monotonic()
            try:
                got = self._receive(0.05)
                if got is not None and got[0].shape[0]:
                    self._push(*got)
                    last_data = time.monotonic()
                    self.backoff.reset()
                elif self.stale_timeout_s and time.monotonic() - last_data > self.stale_timeout_s:
                    raise DeviceLost(f"no data for {self.stale_timeout_s:g} s")
            except Exception as exc:  # the pump must never die: count, log, reconnect
                self._count(error=str(exc) or type(exc).__name__)
                log.warning("%s: device lost: %s", self.name, exc)
                self._device_connected = False
                self._safe_disconnect()
                self._stop.wait(self.backoff.next_delay())
        self._device_connected = False
        self._safe_disconnect()

    def _safe_disconnect(self) -> None:
        try:
            self._disconnect()
        except Exception as exc:  # pragma: no cover - _disconnect must not raise
            log.debug("%s: error while disconnecting: %s", self.name, exc)
