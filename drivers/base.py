"""The source interface: where samples enter dcobserver.

A source (hardware adapter or replay) yields :class:`SampleBlock` objects:
timestamped blocks of the winding signals in SI units. Protocol objects
(``can.Message``, serial bytes, pymodbus responses) never leave ``drivers/``;
everything downstream sees only sample blocks with integer-nanosecond times.

Template-method style, after python-can's ``BusABC``: the public
:meth:`Source.read` owns timeouts, validation and health counting; a backend
overrides only :meth:`Source._read_block` (and optionally :meth:`Source._open` /
:meth:`Source._close`). ``close()`` is idempotent and sources are context managers.
"""

from __future__ import annotations

import abc
import logging
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, ClassVar, NamedTuple

import numpy as np
import numpy.typing as npt

log = logging.getLogger(__name__)

#: Channel names, SI units: V, A, V, A, rad/s.
CHANNELS: tuple[str, ...] = ("va", "ia", "vf", "if", "omega")


class SourceError(Exception):
    """A source failed in a way the caller should see (bad config, cannot open)."""


class SourceClosed(SourceError):
    """The source was closed, or it ended (a replay reached the end of its file)."""


class AdcScale(NamedTuple):
    """How a channel's ADC counts become SI values: ``offset + lsb * count`` (float64).

    The same convention as a recording's ``"adc"`` metadata
    (:mod:`observer.recording.adc`, whose ``AdcScale`` has these fields in this order).

    Attributes
    ----------
    lsb : float
        SI units per count (> 0).
    offset : float
        SI value of count 0.
    bits : int
        Converter resolution (0: not known).
    """

    lsb: float
    offset: float = 0.0
    bits: int = 0

    def values(self, counts: npt.ArrayLike) -> np.ndarray:
        """SI values (float64) of integer ``counts``."""
        return self.offset + self.lsb * np.asarray(counts, dtype=np.float64)


@dataclass(frozen=True)
class SampleBlock:
    """A block of consecutive samples.

    Attributes
    ----------
    t_ns : (n,) int64 array
        Sample times, integer nanoseconds (device time where the protocol carries
        it, else host ``time.monotonic_ns``; see each adapter).
    signals : mapping of channel name -> (n,) float64 array
        A subset of :data:`CHANNELS` in SI units. A source may lack some channels.
    scales : mapping of channel name -> AdcScale
        Channels measured as integer ADC counts, whose values are exactly
        ``scale.values(counts)`` (build such blocks with :meth:`from_counts`).
        Downstream the counts are recovered exactly (:meth:`counts`), so the log
        stores them instead of float64 values. Empty if the source knows none.
    """

    t_ns: np.ndarray
    signals: Mapping[str, np.ndarray]
    scales: Mapping[str, AdcScale] = field(default_factory=dict)

    @classmethod
    def from_counts(
        cls,
        t_ns: npt.ArrayLike,
        counts: Mapping[str, npt.ArrayLike],
        scales: Mapping[str, AdcScale],
        signals: Mapping[str, npt.ArrayLike] | None = None,
    ) -> SampleBlock:
        """A block of ADC counts: each channel of ``counts`` becomes ``scales[c].values(...)``.

        ``signals`` adds channels that have no counts (already in SI units).
        """
        values = {name: scales[name].values(c) for name, c in counts.items()}
        values.update(
            {name: np.asarray(v, dtype=np.float64) for name, v in (signals or {}).items()}
        )
        return cls(t_ns, values, {name: scales[name] for name in counts})  # type: ignore[arg-type]

    def counts(self, channel: str) -> np.ndarray | None:
        """The integer counts of ``channel``, or None if it has no scale (int64)."""
        scale = self.scales.get(channel)
        if scale is None:
            return None
        values = self.signals[channel]
        counts = np.rint((values - scale.offset) / scale.lsb).astype(np.int64)
        return counts

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns, dtype=np.int64)
        if t.ndim != 1:
            raise ValueError(f"t_ns must be one-dimensional, got shape {t.shape}")
        sig = {}
        for name, values in self.signals.items():
            if name not in CHANNELS:
                raise ValueError(f"unknown channel {name!r}; expected one of {CHANNELS}")
            arr = np.asarray(values, dtype=np.float64)
            if arr.shape != t.shape:
                raise ValueError(
                    f"channel {name!r} has {arr.shape[0]} samples, t_ns has {t.shape[0]}"
                )
            sig[name] = arr
        scales = {}
        for name, scale in self.scales.items():
            if name not in sig:
                raise ValueError(f"scale for channel {name!r}, which the block does not have")
            scales[name] = AdcScale(*scale)
            if not (np.isfinite(scales[name].lsb) and scales[name].lsb > 0):
                raise ValueError(f"scale of {name!r}: lsb must be > 0, got {scales[name].lsb}")
        object.__setattr__(self, "t_ns", t)
        object.__setattr__(self, "signals", MappingProxyType(sig))
        object.__setattr__(self, "scales", MappingProxyType(scales))

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def channels(self) -> tuple[str, ...]:
        return tuple(c for c in CHANNELS if c in self.signals)


@dataclass
class SourceHealth:
    """Counters a source keeps; read a consistent copy with :meth:`Source.health`."""

    connected: bool = False
    blocks: int = 0
    samples: int = 0
    dropped: int = 0  # samples known lost (sequence gaps, overruns at the device)
    bad_samples: int = 0  # non-finite samples removed from blocks
    errors: int = 0  # bad frames, protocol errors, exceptions in the backend
    reconnects: int = 0
    last_error: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in self.__dict__.items() if k != "extra"}
        out.update(self.extra)
        return out


class Source(abc.ABC):
    """Abstract source of :class:`SampleBlock` objects.

    Subclasses implement :meth:`_read_block`; they may override :meth:`_open`
    and :meth:`_close`. Health counters are updated under a lock so the
    observer can read them from another thread.
    """

    #: Registry name (e.g. "replay", "can"); set by subclasses.
    name: str = "source"

    #: Frozen dataclass of this source's options (the ``[source.options]`` table
    #: of a config file), validated strictly by :func:`observer.config.build`.
    Options: ClassVar[type | None] = None

    @classmethod
    def from_config(cls, table: Mapping[str, Any], *, source: str, base_dir: Path) -> Source:
        """Build from the ``[source.options]`` table of config file ``source``.

        The config file says ``[source] kind = "<name>"`` and gives this
        source's options in ``[source.options]``. Unknown keys and bad values
        raise :class:`observer.config.ConfigError` naming the key and the file;
        relative paths are taken from ``base_dir`` (the config file's folder).
        Subclasses set :attr:`Options` and accept an instance of it as the
        only positional argument of ``__init__``.
        """
        from observer.config import ConfigError, build

        if cls.Options is None:
            raise ConfigError(f"{source}: source {cls.name!r} cannot be configured from a file")
        options: Any = build(
            cls.Options, dict(table), source=source, base_dir=base_dir, prefix="source.options"
        )
        return cls(options)  # type: ignore[call-arg]

    def __init__(self) -> None:
        self._health = SourceHealth()
        self._lock = threading.Lock()
        self._closed = False
        self._opened = False

    # -- backend hooks -------------------------------------------------------

    def _open(self) -> None:  # noqa: B027 - optional hook
        """Connect to the device. Called once, by the first :meth:`read`."""

    @abc.abstractmethod
    def _read_block(self, timeout: float | None) -> SampleBlock | None:
        """Return the next block, or None if none arrived within ``timeout`` seconds.

        Raise :class:`SourceClosed` when the source has ended for good.
        """

    def _close(self) -> None:  # noqa: B027 - optional hook
        """Release the device. Called once."""

    # -- public API ------------------------------------------------------------

    def read(self, timeout: float | None = None) -> SampleBlock | None:
        """Next block of samples, or None on timeout.

        Non-finite samples are removed and counted in ``bad_samples``; a block
        left empty is swallowed (None is returned). Raises :class:`SourceClosed`
        after :meth:`close` or when the source has ended.
        """
        if self._closed:
            raise SourceClosed(f"{self.name} source is closed")
        if not self._opened:
            self._open()
            self._opened = True
            self._count(connected=True)
        block = self._read_block(timeout)
        if block is None:
            return None
        finite = np.ones(len(block), dtype=bool)
        for values in block.signals.values():
            finite &= np.isfinite(values)
        n_bad = int(len(block) - finite.sum())
        if n_bad:
            block = SampleBlock(
                block.t_ns[finite], {k: v[finite] for k, v in block.signals.items()}, block.scales
            )
        self._count(blocks=1, samples=len(block), bad_samples=n_bad)
        return block if len(block) else None

    def __iter__(self) -> Iterator[SampleBlock]:
        """Blocks until the source ends."""
        while True:
            try:
                block = self.read(timeout=1.0)
            except SourceClosed:
                return
            if block is not None:
                yield block

    def health(self) -> dict[str, Any]:
        """A consistent copy of the health counters."""
        with self._lock:
            return self._health.as_dict()

    def _count(self, **changes: Any) -> None:
        """Add to counters (ints) or set fields (others) under the lock."""
        with self._lock:
            for key, value in changes.items():
                if key == "error":
                    self._health.errors += 1
                    self._health.last_error = str(value)
                elif (
                    hasattr(self._health, key)
                    and isinstance(value, int)
                    and not isinstance(value, bool)
                ):
                    setattr(self._health, key, getattr(self._health, key) + value)
                elif hasattr(self._health, key):
                    setattr(self._health, key, value)
                else:
                    self._health.extra[key] = value

    def close(self) -> None:
        """Release the source. Idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            if self._opened:
                self._close()
        finally:
            self._count(connected=False)

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def monotonic_ns() -> int:
    """Host monotonic clock, the timestamp of sources whose protocol carries none."""
    return time.monotonic_ns()
