"""Replay source: recordings (MCAP or CSV) played back as if they came from a drive.

MCAP files are streamed message by message (a daemon log of hours is never
loaded whole) and tolerate a file cut short by a crash: the blocks before the
cut are replayed and the cut is logged. Unlike :func:`observer.recording.read_mcap`,
no uniform time base is demanded, so a log holding gaps (a source that
stalled) or non-finite samples replays as it was recorded and the observer
downstream sees the same faults the live daemon saw. CSV files are read whole
through :func:`observer.recording.read_recording`.

Pacing: ``speed = 1`` releases each block when its last sample would have been
measured (real time), ``speed = N`` N times faster, ``speed = 0`` as fast as
the reader asks.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.base import SampleBlock, Source, SourceClosed, SourceError

log = logging.getLogger(__name__)

_NS = 1_000_000_000


def _positive(x: float) -> str | None:
    return None if x > 0 else f"must be > 0, got {x}"


@dataclass(frozen=True)
class ReplayOptions:
    """Options of the replay source (``[source.options]`` with ``kind = "replay"``)."""

    path: str = dataclasses.field(
        default="", metadata={"path": True, "help": "recording to replay: .mcap, .csv, .csv.gz"}
    )
    speed: float = dataclasses.field(
        default=1.0,
        metadata={"min": 0.0, "help": "1 = real time, N = N x real time, 0 = as fast as possible"},
    )
    block_s: float = dataclasses.field(
        default=0.05, metadata={"check": _positive, "help": "length of one block (s)"}
    )
    loop: bool = dataclasses.field(
        default=False, metadata={"help": "start again at the end, times continuing"}
    )

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("'path' (the recording to replay) is required")


def iter_mcap_blocks(path: str | os.PathLike[str]) -> Iterator[tuple[np.ndarray, dict]]:
    """Stream the sample blocks of an MCAP file in file order.

    Yields ``(t_ns, signals)`` per message on
    :data:`observer.recording.SAMPLES_TOPIC`; stops quietly (with a warning) where
    the file is cut; a malformed message is logged and skipped.
    """
    from mcap.records import Channel, Message

    from observer.recording import SAMPLES_TOPIC, McapRecordStream, parse_sample_block

    name = os.fspath(path)
    size = os.path.getsize(name)
    channels: dict[int, Channel] = {}
    with open(name, "rb") as stream:
        records = McapRecordStream(stream, size)
        index = 0
        for record in records:
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or channel.topic != SAMPLES_TOPIC:
                    continue
                index += 1
                try:
                    yield parse_sample_block(record.data)
                except ValueError as exc:
                    log.warning("%s: skipping sample message %d: %s", name, index, exc)
        if records.cut_reason is not None:
            log.warning(
                "%s: MCAP file ends early (%s); replayed up to the cut", name, records.cut_reason
            )


def _iter_file_blocks(path: str) -> Iterator[tuple[np.ndarray, dict]]:
    if path.lower().endswith(".mcap"):
        yield from iter_mcap_blocks(path)
        return
    from observer.recording import read_recording

    rec = read_recording(path)
    t_ns = np.rint(rec.t * _NS).astype(np.int64)
    step = 4096
    for start in range(0, rec.n_samples, step):
        sl = slice(start, start + step)
        yield t_ns[sl], {c: np.asarray(rec.signals[c][sl]) for c in rec.channels}


class ReplaySource(Source):
    """Plays a recording back in blocks of ``block_s`` seconds, paced by ``speed``.

    Parameters
    ----------
    options : ReplayOptions
    """

    name = "replay"
    Options = ReplayOptions

    def __init__(self, options: ReplayOptions) -> None:
        super().__init__()
        if not os.path.isfile(options.path):
            raise SourceError(f"replay: recording {options.path} not found")
        self.options = options
        self._messages: Iterator[tuple[np.ndarray, dict]] | None = None
        self._pending_t: list[np.ndarray] = []
        self._pending_s: list[dict] = []
        self._offset_ns = 0  # added to times on each loop
        self._span_ns = 0  # last time seen - first time + one period
        self._first_ns: int | None = None
        self._last_ns: int | None = None
        self._start_wall_ns = 0
        self._start_data_ns = 0
        self._loops = 0
        self._period_ns = 0
        self._ready: SampleBlock | None = None

    @classmethod
    def of(cls, path: str | Path, **options: object) -> ReplaySource:
        """Shorthand: ``ReplaySource.of("rec.mcap", speed=0)``."""
        return cls(ReplayOptions(path=str(path), **options))  # type: ignore[arg-type]

    def _open(self) -> None:
        self._messages = _iter_file_blocks(self.options.path)
        self._start_wall_ns = time.monotonic_ns()
        self._count(path=self.options.path, speed=self.options.speed)

    def _next_message(self) -> tuple[np.ndarray, dict] | None:
        assert self._messages is not None
        for t_ns, signals in self._messages:
            if t_ns.size == 0:
                continue
            if self._first_ns is None:
                self._first_ns = int(t_ns[0])
                self._start_data_ns = int(t_ns[0])
            return t_ns + self._offset_ns, signals
        if not self.options.loop or self._first_ns is None or self._last_ns is None:
            return None
        # Loop: times continue one median period after the last sample.
        self._loops += 1
        self._count(loops=self._loops)
        period = self._period_ns or 1
        self._offset_ns = self._last_ns + period - self._first_ns  # _last_ns: output time
        self._messages = _iter_file_blocks(self.options.path)
        for t_ns, signals in self._messages:
            if t_ns.size:
                return t_ns + self._offset_ns, signals
        return None

    def _fill(self, until_ns: int) -> bool:
        """Pull messages until the pending samples reach ``until_ns``; False at the end."""
        while not self._pending_t or int(self._pending_t[-1][-1]) < until_ns:
            message = self._next_message()
            if message is None:
                return False
            t_ns, signals = message
            if t_ns.size > 1 and not self._period_ns:
                self._period_ns = int(np.median(np.diff(t_ns)))
            self._pending_t.append(t_ns)
            self._pending_s.append(signals)
            self._last_ns = int(t_ns[-1])
        return True

    def _take_block(self) -> SampleBlock | None:
        if not self._pending_t:
            if not self._fill(0):
                return None
        start = int(self._pending_t[0][0])
        block_ns = int(self.options.block_s * _NS)
        more = self._fill(start + block_ns)
        t_all = np.concatenate(self._pending_t)
        names = list(self._pending_s[0])
        sig_all = {c: np.concatenate([s[c] for s in self._pending_s]) for c in names}
        cut = int(np.searchsorted(t_all, start + block_ns, side="left")) if more else t_all.size
        cut = max(cut, 1)
        block = SampleBlock(t_all[:cut], {c: v[:cut] for c, v in sig_all.items()})
        if cut < t_all.size:
            self._pending_t = [t_all[cut:]]
            self._pending_s = [{c: v[cut:] for c, v in sig_all.items()}]
        else:
            self._pending_t, self._pending_s = [], []
        return block

    def _read_block(self, timeout: float | None) -> SampleBlock | None:
        if self._ready is None:
            self._ready = self._take_block()
            if self._ready is None:
                raise SourceClosed(f"replay of {self.options.path} reached the end")
        block = self._ready
        if self.options.speed > 0:
            due_ns = self._start_wall_ns + int(
                (int(block.t_ns[-1]) - self._start_data_ns) / self.options.speed
            )
            wait_s = (due_ns - time.monotonic_ns()) / _NS
            if wait_s > 0:
                if timeout is not None and wait_s > timeout:
                    time.sleep(timeout)
                    return None
                time.sleep(wait_s)
        self._ready = None
        return block

    def _close(self) -> None:
        close = getattr(self._messages, "close", None)
        if close is not None:
            close()
        self._messages = None
