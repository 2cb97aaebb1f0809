"""Reading MCAP recordings, including files a crash or a cut left unfinished.

The messages on :data:`~observer.recording.sample_block.SAMPLES_TOPIC` are
concatenated in file order; other topics in the same file are ignored. A file
whose writer never finished (a crash) or that was cut short is read up to the
last complete chunk: :class:`McapRecordStream` walks such a file record by
record and stops quietly at the cut (the daemon's log recovery and the replay
source use it too). Times are stored as integer nanoseconds, so ``t`` round
trips to within 0.5 ns (exactly when it is a whole number of nanoseconds,
``t == t_ns / 1e9``); the signals round trip exactly.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, Any, Final

import numpy as np
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader

from observer.recording.adc import ADC_KEY, AdcScale
from observer.recording.base import (
    FloatArray,
    IntArray,
    PathArg,
    Recording,
    RecordingError,
    _loads_strict,
    _Location,
    _raise_problem,
    _samples_problem,
)
from observer.recording.sample_block import (
    METADATA_NAME,
    NS_PER_S,
    SAMPLES_TOPIC,
    _SampleBlockError,
)
from observer.recording.sample_proto import parse_samples

_log = logging.getLogger(__name__)

_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class _RawBlock:
    log_time: int
    data: bytes
    message_encoding: str


@dataclass
class _McapContent:
    blocks: list[_RawBlock] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    complete: bool = True
    cut_reason: str = ""
    topics: set[str] = field(default_factory=set)
    size: int = 0


def _scan_mcap_indexed(stream: IO[bytes]) -> _McapContent:
    """Read a finished file through its summary section."""
    reader = make_reader(stream)
    content = _McapContent()
    summary = reader.get_summary()
    if summary is not None:
        content.topics = {c.topic for c in summary.channels.values()}
    for _schema, channel, message in reader.iter_messages(
        topics=[SAMPLES_TOPIC], log_time_order=False
    ):
        content.blocks.append(_RawBlock(message.log_time, message.data, channel.message_encoding))
    content.metadata = [m for m in reader.iter_metadata() if m.name == METADATA_NAME]
    return content


class McapRecordStream:
    """The records of an MCAP byte stream in file order, ending quietly at a cut.

    A file a crash left behind has no footer (``make_reader`` cannot open it) and
    may end inside a record. Iterating this yields every complete record and
    stops at the first that cannot be read; ``cut_reason`` then says why (None
    after a complete file). The daemon's log recovery and the replay source read
    cut logs through this too.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self.stream = stream
        self.size = max(size, 1)
        self.cut_reason: str | None = None

    def __iter__(self) -> Iterator[Any]:
        # A record longer than the file can only come from a cut; CRCs catch a cut chunk.
        records = StreamReader(self.stream, validate_crcs=True, record_size_limit=self.size).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except Exception as exc:
                # A cut shows up as whichever error the library meets first (EndOfFile,
                # struct.error, a zstd/lz4 error, a CRC mismatch...): all mean "stop here".
                self.cut_reason = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                return
            yield record


def _scan_mcap_streaming(stream: IO[bytes], size: int) -> _McapContent:
    """Read records in file order, stopping quietly where the file is cut."""
    records = McapRecordStream(stream, size)
    channels: dict[int, Channel] = {}
    content = _McapContent()
    for record in records:
        if isinstance(record, Channel):
            channels[record.id] = record
            content.topics.add(record.topic)
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None and channel.topic == SAMPLES_TOPIC:
                content.blocks.append(
                    _RawBlock(record.log_time, record.data, channel.message_encoding)
                )
        elif isinstance(record, Metadata) and record.name == METADATA_NAME:
            content.metadata.append(record)
    if records.cut_reason is not None:
        content.complete = False
        content.cut_reason = records.cut_reason
    return content


def _scan_mcap(stream: IO[bytes], name: str) -> _McapContent:
    size = stream.seek(0, os.SEEK_END)
    if size == 0:
        raise RecordingError("file is empty", path=name)
    stream.seek(0)
    head = stream.read(len(_MCAP_MAGIC))
    if head != _MCAP_MAGIC:
        raise RecordingError(f"not an MCAP file ({_what_it_is(head)})", path=name)
    finished = False
    if size >= 2 * len(_MCAP_MAGIC):
        stream.seek(-len(_MCAP_MAGIC), os.SEEK_END)
        finished = stream.read() == _MCAP_MAGIC
    content = None
    if finished:
        stream.seek(0)
        try:
            content = _scan_mcap_indexed(stream)
        except Exception as exc:
            # A damaged summary or chunk: read what precedes the damage instead.
            _log.debug("%s: indexed MCAP read failed (%s); streaming instead", name, exc)
    if content is None:
        stream.seek(0)
        content = _scan_mcap_streaming(stream, size)
    content.size = size
    return content


def _what_it_is(head: bytes) -> str:
    """What a file that is not MCAP seems to be, from its first bytes."""
    if head.startswith(b"\x1f\x8b"):
        return "it is gzip-compressed: a .csv.gz?"
    if head.startswith(b"\x89MCAP"):
        return "an MCAP magic of another version"
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError:
        return "no MCAP magic bytes at the start"
    if text.isprintable() or text.rstrip("\r\n").isprintable():
        return "it holds text: a CSV file? name it .csv"
    return "no MCAP magic bytes at the start"


def _mcap_metadata(records: Sequence[Metadata], name: str) -> dict[str, Any]:
    if not records:
        return {}
    record = records[-1]  # the latest record wins
    if "json" not in record.metadata:
        raise RecordingError(f"metadata record {METADATA_NAME!r} has no 'json' key", path=name)
    try:
        metadata = _loads_strict(record.metadata["json"])
    except ValueError as exc:
        raise RecordingError(
            f"metadata record {METADATA_NAME!r} is not valid JSON: {exc}", path=name
        ) from exc
    if not isinstance(metadata, dict):
        raise RecordingError(
            f"metadata record {METADATA_NAME!r} must hold a JSON object, "
            f"got {type(metadata).__name__}",
            path=name,
        )
    return metadata


def _message_where(index: int, log_time: int) -> str:
    return f"message {index} on {SAMPLES_TOPIC!r} (log time {log_time} ns)"


def read_mcap(path: PathArg, *, notes: list[str] | None = None) -> Recording:
    """Read an MCAP recording.

    The messages on :data:`SAMPLES_TOPIC` are concatenated in file order and
    validated as a whole; other topics are ignored. A file whose writer never
    called ``finish()`` or that was cut short is read up to the last complete
    chunk (a warning is logged).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.
    notes : list, optional
        Where to append what a reader should know (the file is cut short)
        instead of logging it as a warning.

    Returns
    -------
    Recording
        ``t`` is ``t_ns / 1e9``.

    Raises
    ------
    RecordingError
        Naming the message (1-based index on :data:`SAMPLES_TOPIC`, and its log
        time), the sample within it and the column of the first problem.
    """
    name = os.fspath(path)
    try:
        with open(name, "rb") as stream:
            content = _scan_mcap(stream, name)
    except OSError as exc:
        raise RecordingError(f"cannot read file: {exc.strerror or exc}", path=name) from exc
    if not content.blocks:
        if not content.complete:
            raise RecordingError(
                f"cut short (or still being written) after {content.size} bytes, before its "
                f"first complete message on {SAMPLES_TOPIC!r}: nothing to read",
                path=name,
            )
        others = sorted(content.topics - {SAMPLES_TOPIC})
        declared = SAMPLES_TOPIC in content.topics  # a writer stopped before the first sample
        other = " other" if declared else ""
        found = f"; its{other} topics: {', '.join(others)}" if others else (
            f"; it has no{other} topics"
        )  # fmt: skip
        if declared:
            found = f" (the topic is declared, the recording empty){found}"
        raise RecordingError(f"no messages on topic {SAMPLES_TOPIC!r}{found}", path=name)
    if not content.complete:
        note = (
            f"{name}: MCAP file is unfinished or cut short ({content.cut_reason}); using the "
            f"{len(content.blocks)} complete sample blocks before the cut"
        )
        if notes is None:
            _log.warning("%s", note)
        else:
            notes.append(note)
    metadata = _mcap_metadata(content.metadata, name)

    times: list[IntArray] = []
    columns: dict[str, list[FloatArray]] = {}
    scales: dict[str, set[AdcScale]] = {}
    for index, raw in enumerate(content.blocks, start=1):
        where = _message_where(index, raw.log_time)
        try:
            t_ns, signals, block_scales = parse_samples(raw.message_encoding, raw.data)
        except _SampleBlockError as exc:
            raise RecordingError(
                f"malformed sample block: {exc}",
                path=name,
                where=where,
                column=exc.column,
                message_index=index,
            ) from exc
        if index == 1:
            columns = {channel: [] for channel in signals}
        elif tuple(signals) != tuple(columns):
            raise RecordingError(
                f"channels {', '.join(signals)} differ from those of message 1 "
                f"({', '.join(columns)})",
                path=name,
                where=where,
                message_index=index,
            )
        times.append(t_ns)
        for channel, values in signals.items():
            columns[channel].append(values)
        for channel, scale in block_scales.items():
            scales.setdefault(channel, set()).add(scale)

    sizes = np.array([block.size for block in times], dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    log_times = [raw.log_time for raw in content.blocks]
    t = np.concatenate(times) / NS_PER_S
    signal_arrays = {channel: np.concatenate(parts) for channel, parts in columns.items()}

    def locate(sample: int) -> _Location:
        block = int(np.searchsorted(starts, sample, side="right")) - 1
        within = int(sample - starts[block]) + 1
        return _Location(
            where=f"{_message_where(block + 1, log_times[block])}, sample {within}",
            message_index=block + 1,
        )

    problem = _samples_problem(t, list(signal_arrays.items()))
    if problem is not None:
        _raise_problem(problem, name, locate)
    if ADC_KEY not in metadata:
        # Counts stored with one scale throughout (a daemon log of an ADC source): say so,
        # so that writing the recording again stores counts again.
        table = {c: next(iter(s)).as_metadata() for c, s in scales.items() if len(s) == 1}
        if table:
            metadata = {**metadata, ADC_KEY: table}
    return Recording(t=t, signals=signal_arrays, metadata=metadata)
