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
import json
import logging
import os
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.base import AdcScale, SampleBlock, Source, SourceClosed, SourceError

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


def iter_mcap_blocks(path: str | os.PathLike[str]) -> Iterator[SampleBlock]:
    """Stream the sample blocks of an MCAP file in file order.

    Yields one :class:`SampleBlock` per message on
    :data:`observer.recording.SAMPLES_TOPIC` (protobuf or the older JSON
    blocks), with the ADC scales of channels stored as counts, or declared by
    the file's ``"adc"`` metadata; stops quietly (with a warning) where the
    file is cut; a malformed message is logged and skipped.
    """
    from mcap.records import Channel, Message, Metadata

    from observer.recording import (
        METADATA_NAME,
        SAMPLES_TOPIC,
        McapRecordStream,
        adc_scales,
        parse_samples,
    )

    name = os.fspath(path)
    size = os.path.getsize(name)
    channels: dict[int, Channel] = {}
    declared: dict[str, AdcScale] = {}
    with open(name, "rb") as stream:
        records = McapRecordStream(stream, size)
        index = 0
        for record in records:
            if isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata) and record.name == METADATA_NAME:
                try:
                    metadata = json.loads(record.metadata.get("json", "{}"))
                    declared = {c: AdcScale(*s) for c, s in adc_scales(metadata).items()}
                except (ValueError, AttributeError) as exc:
                    log.warning("%s: ignoring the ADC scales of its metadata: %s", name, exc)
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or channel.topic != SAMPLES_TOPIC:
                    continue
                index += 1
                try:
                    t_ns, signals, scales = parse_samples(channel.message_encoding, record.data)
                    block_scales = {c: s for c, s in declared.items() if c in signals}
                    block_scales.update({c: AdcScale(*s) for c, s in scales.items()})
                    yield SampleBlock(t_ns, signals, block_scales)
                except ValueError as exc:
                    log.warning("%s: skipping sample message %d: %s", name, index, exc)
        if records.cut_reason is not None:
            log.warning(
                "%s: MCAP file ends early (%s); replayed up to the cut", name, records.cut_reason
            )


def _iter_file_blocks(path: str) -> Iterator[SampleBlock]:
    from observer.recording import final_path

    if final_path(path).name.lower().endswith(".mcap"):
        yield from iter_mcap_blocks(path)
        return
    from observer.recording import adc_scales, read_recording

    rec = read_recording(path)
    scales = {c: AdcScale(*s) for c, s in adc_scales(rec.metadata).items()}
    t_ns = np.rint(rec.t * _NS).astype(np.int64)
    step = 4096
    for start in range(0, rec.n_samples, step):
        sl = slice(start, start + step)
        signals = {c: np.asarray(rec.signals[c][sl]) for c in rec.channels}
        yield SampleBlock(t_ns[sl], signals, scales)


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
            what = "is a directory, not a file" if os.path.isdir(options.path) else "not found"
            raise SourceError(f"replay: recording {options.path} {what}")
        self.options = options
        self._messages: Iterator[SampleBlock] | None = None
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
        self._scales: Mapping[str, AdcScale] = {}

    @classmethod
    def of(cls, path: str | Path, **options: object) -> ReplaySource:
        """Shorthand: ``ReplaySource.of("rec.mcap", speed=0)``."""
        return cls(ReplayOptions(path=str(path), **options))  # type: ignore[arg-type]

    def _open(self) -> None:
        self._messages = _iter_file_blocks(self.options.path)
        self._start_wall_ns = time.monotonic_ns()
        self._count(path=self.options.path, speed=self.options.speed)

    def _next_message(self) -> SampleBlock | None:
        assert self._messages is not None
        for block in self._messages:
            if len(block) == 0:
                continue
            if self._first_ns is None:
                self._first_ns = int(block.t_ns[0])
                self._start_data_ns = int(block.t_ns[0])
            return self._shifted(block)
        if not self.options.loop or self._first_ns is None or self._last_ns is None:
            return None
        # Loop: times continue one median period after the last sample.
        self._loops += 1
        self._count(loops=self._loops)
        period = self._period_ns or 1
        self._offset_ns = self._last_ns + period - self._first_ns  # _last_ns: output time
        self._messages = _iter_file_blocks(self.options.path)
        for block in self._messages:
            if len(block):
                return self._shifted(block)
        return None

    def _shifted(self, block: SampleBlock) -> SampleBlock:
        if not self._offset_ns:
            return block
        return SampleBlock(block.t_ns + self._offset_ns, block.signals, block.scales)

    def _fill(self, until_ns: int) -> bool:
        """Pull messages until the pending samples reach ``until_ns``; False at the end."""
        while not self._pending_t or int(self._pending_t[-1][-1]) < until_ns:
            message = self._next_message()
            if message is None:
                return False
            t_ns = message.t_ns
            if t_ns.size > 1 and not self._period_ns:
                self._period_ns = int(np.median(np.diff(t_ns)))
            self._pending_t.append(t_ns)
            self._pending_s.append(dict(message.signals))
            self._scales = message.scales
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
        scales = {c: v for c, v in self._scales.items() if c in sig_all}
        block = SampleBlock(t_all[:cut], {c: v[:cut] for c, v in sig_all.items()}, scales)
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
