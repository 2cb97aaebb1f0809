"""Recordings of DC-motor winding signals: the in-memory type and its file formats.

A :class:`Recording` is a frozen, validated set of uniformly sampled signals:
the time base ``t`` (s) plus any non-empty subset of the channels in
:data:`CHANNELS` (armature voltage and current, field voltage and current,
shaft speed), all in SI units (see :data:`UNITS`).

Two file formats are read and written:

CSV (``.csv``, or gzip-compressed ``.csv.gz``)
    A header row naming the columns (``t`` plus at least one channel, in any
    order), then one row per sample. Lines starting with ``#`` before the
    header are comments; the recording's metadata is kept in one of them as
    ``# dcobserver-metadata: {json}``. Numbers are written with ``repr``, so a
    round trip reproduces every float64 exactly.
MCAP (``.mcap``)
    ZSTD-compressed chunks; one JSON message on :data:`SAMPLES_TOPIC` per block
    of samples, ``{"t_ns": [...], "va": [...], ...}`` (see
    :data:`SAMPLE_BLOCK_SCHEMA`), and the metadata in a Metadata record named
    :data:`METADATA_NAME`. Other topics in the same file are ignored, and a file
    whose writer never finished (a crash) or that was cut short is read up to
    the last complete chunk. Times are stored as integer nanoseconds, so ``t``
    round trips to within 0.5 ns (exactly when it is a whole number of
    nanoseconds, ``t == t_ns / 1e9``); the signals round trip exactly.

Every problem found in a file raises :class:`RecordingError`, whose one-line
message names the file and, where known, the row (CSV: the 1-based line number
in the file) or the message (MCAP) and the column.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import logging
import math
import os
import warnings
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property, partial
from types import MappingProxyType
from typing import IO, Any, Final, NoReturn

import numpy as np
import numpy.typing as npt
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

__all__ = [
    "CHANNELS",
    "METADATA_NAME",
    "SAMPLES_SCHEMA_NAME",
    "SAMPLES_TOPIC",
    "SAMPLE_BLOCK_SCHEMA",
    "UNITS",
    "Recording",
    "RecordingError",
    "parse_sample_block",
    "read_csv",
    "read_mcap",
    "read_recording",
    "sample_block_message",
    "validate_timebase",
    "write_csv",
    "write_mcap",
    "write_recording",
]

_log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
PathArg = str | os.PathLike[str]

CHANNELS: Final[tuple[str, ...]] = ("va", "ia", "vf", "if", "omega")
"""Signal channels a recording may carry, in the order they are written."""

UNITS: Final[dict[str, str]] = {
    "t": "s",
    "va": "V",
    "ia": "A",
    "vf": "V",
    "if": "A",
    "omega": "rad/s",
}
"""SI unit of the time column and of every channel."""

_MEANINGS: Final[dict[str, str]] = {
    "t": "time",
    "va": "armature voltage",
    "ia": "armature current",
    "vf": "field voltage",
    "if": "field current",
    "omega": "shaft angular speed",
}

SAMPLES_TOPIC: Final = "/samples"
SAMPLES_SCHEMA_NAME: Final = "dcobserver.SampleBlock"
METADATA_NAME: Final = "dcobserver.recording"

SAMPLE_BLOCK_SCHEMA: Final[dict[str, Any]] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": SAMPLES_SCHEMA_NAME,
    "description": (
        "A block of uniformly sampled DC-motor winding signals. Every array has the "
        "length of t_ns; at least one signal is present."
    ),
    "type": "object",
    "properties": {
        "t_ns": {
            "description": "Sample times, integer nanoseconds.",
            "type": "array",
            "items": {"type": "integer"},
            "minItems": 1,
        },
        **{
            name: {
                "description": f"{_MEANINGS[name].capitalize()} ({UNITS[name]}).",
                "type": "array",
                "items": {"type": "number"},
                "minItems": 1,
            }
            for name in CHANNELS
        },
    },
    "required": ["t_ns"],
    "minProperties": 2,
    "additionalProperties": False,
}
"""JSON schema (draft 2020-12) of one message on :data:`SAMPLES_TOPIC`."""

_TIME: Final = "t"
_COLUMNS: Final[tuple[str, ...]] = (_TIME, *CHANNELS)
_MIN_SAMPLES: Final = 2
_DEFAULT_REL_TOL: Final = 0.01
_METADATA_PREFIX: Final = "# dcobserver-metadata:"
_CSV_WRITE_ROWS: Final = 65536
_GZIP_LEVEL: Final = 6
# Small enough that a cut file loses little, large enough to compress well.
_MCAP_CHUNK_SIZE: Final = 256 * 1024
_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
_NS_PER_S: Final = 1e9


# --------------------------------------------------------------------------- errors


class RecordingError(ValueError):
    """A recording (file or in-memory) is unreadable or invalid.

    ``str(err)`` is one user-facing line naming the file and, where known, the
    location and column, e.g. ``"recording.csv: row 17, column 'ia': value is NaN"``.

    Parameters
    ----------
    problem : str
        What is wrong, without the location.
    path : str or os.PathLike, optional
        The file, if the recording came from one.
    row : int, optional
        1-based row: for CSV the line number in the file (header and comment
        lines included); for in-memory data the 1-based sample number.
    column : str, optional
        The column (``"t"`` or a channel) concerned.
    where : str, optional
        A location description used instead of ``row N`` (MCAP messages).
    message_index : int, optional
        1-based index of the MCAP message on :data:`SAMPLES_TOPIC` concerned.

    Attributes
    ----------
    path, row, column, message_index, problem
        As given; ``path`` as a ``str``.
    """

    def __init__(
        self,
        problem: str,
        *,
        path: PathArg | None = None,
        row: int | None = None,
        column: str | None = None,
        where: str | None = None,
        message_index: int | None = None,
    ) -> None:
        self.problem = problem
        self.path: str | None = None if path is None else os.fspath(path)
        self.row = row
        self.column = column
        self.where = where
        self.message_index = message_index
        location = where if where is not None else (f"row {row}" if row is not None else None)
        if column is not None:
            location = f"{location}, column {column!r}" if location else f"column {column!r}"
        text = ": ".join(part for part in (self.path, location, problem) if part)
        super().__init__(" ".join(text.splitlines()))

    def __reduce__(self) -> tuple[Any, ...]:
        # The keyword-only arguments would be lost by the default exception pickling.
        rebuild = partial(
            RecordingError,
            self.problem,
            path=self.path,
            row=self.row,
            column=self.column,
            where=self.where,
            message_index=self.message_index,
        )
        return (rebuild, ())


@dataclass(frozen=True)
class _Problem:
    """A validation failure before it is given a location."""

    text: str
    index: int | None = None  # 0-based sample index, if the problem is at one sample
    column: str | None = None


@dataclass(frozen=True)
class _Location:
    row: int | None = None
    where: str | None = None
    message_index: int | None = None


_Locator = Callable[[int], _Location]


def _raise_problem(problem: _Problem, path: PathArg | None, locate: _Locator) -> NoReturn:
    location = _Location() if problem.index is None else locate(problem.index)
    raise RecordingError(
        problem.text,
        path=path,
        row=location.row,
        column=problem.column,
        where=location.where,
        message_index=location.message_index,
    )


def _row_locator(row_offset: int) -> _Locator:
    return lambda index: _Location(row=row_offset + index + 1)


# --------------------------------------------------------------------------- validation


def _nonfinite_text(value: float) -> str:
    return "value is NaN" if math.isnan(value) else f"value is {value}"


def _first_nonfinite(columns: Sequence[tuple[str, FloatArray]]) -> _Problem | None:
    """First non-finite cell in row-major order (ties go to the earlier column)."""
    found: _Problem | None = None
    for name, values in columns:
        bad = ~np.isfinite(values)
        if bad.any():
            index = int(np.argmax(bad))
            if found is None or (found.index is not None and index < found.index):
                found = _Problem(_nonfinite_text(float(values[index])), index, name)
    return found


def _timebase_problem(t: FloatArray, rel_tol: float) -> _Problem | None:
    if t.size < _MIN_SAMPLES:
        return _Problem(f"fewer than {_MIN_SAMPLES} samples (found {t.size})")
    nonfinite = _first_nonfinite([(_TIME, t)])
    if nonfinite is not None:
        return nonfinite
    periods = np.diff(t)
    not_increasing = periods <= 0
    if not_increasing.any():
        i = int(np.argmax(not_increasing))
        return _Problem(
            f"time not strictly increasing: t = {t[i + 1]:.9g} s follows t = {t[i]:.9g} s",
            i + 1,
            _TIME,
        )
    median_period = float(np.median(periods))
    off = np.abs(periods - median_period) > rel_tol * median_period
    if off.any():
        i = int(np.argmax(off))
        return _Problem(
            f"non-uniform sampling: period {periods[i]:.6g} s since the previous sample, "
            f"expected {median_period:.6g} s (the median period) within {rel_tol * 100:g}%",
            i + 1,
            _TIME,
        )
    return None


def _samples_problem(
    t: FloatArray, signals: Sequence[tuple[str, FloatArray]], rel_tol: float = _DEFAULT_REL_TOL
) -> _Problem | None:
    """The first problem with a table of samples, in the order a reader meets them."""
    if t.size < _MIN_SAMPLES:
        return _Problem(f"fewer than {_MIN_SAMPLES} samples (found {t.size})")
    nonfinite = _first_nonfinite([(_TIME, t), *signals])
    if nonfinite is not None:
        return nonfinite
    return _timebase_problem(t, rel_tol)


def validate_timebase(
    t: npt.ArrayLike,
    *,
    path: PathArg | None = None,
    rel_tol: float = _DEFAULT_REL_TOL,
    row_offset: int = 0,
) -> None:
    """Check that ``t`` is a usable time base.

    It must hold at least 2 finite samples, be strictly increasing, and every
    sample period must be within ``rel_tol`` of the median period.

    Parameters
    ----------
    t : array_like
        Sample times (s), 1-D.
    path : str or os.PathLike, optional
        File named in the error message.
    rel_tol : float
        Largest allowed relative deviation of one sample period from the median.
    row_offset : int
        Number of rows before the first sample (e.g. header and comment lines of
        a CSV file): sample ``i`` (0-based) is reported as row ``row_offset + i + 1``.

    Raises
    ------
    RecordingError
        Naming the first offending row, with the period found and expected for
        non-uniform sampling.
    ValueError
        If ``rel_tol`` is not positive.
    """
    if not rel_tol > 0:
        raise ValueError(f"rel_tol must be > 0, got {rel_tol!r}")
    times = _as_float_vector(t, _TIME, path=path)
    problem = _timebase_problem(times, rel_tol)
    if problem is not None:
        _raise_problem(problem, path, _row_locator(row_offset))


def _as_float_vector(values: object, name: str, *, path: PathArg | None = None) -> FloatArray:
    """A fresh read-only float64 1-D copy of ``values``; numbers only (no strings)."""
    try:
        array = np.asarray(values)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"not an array of numbers: {exc}", path=path, column=name) from exc
    if array.dtype.kind not in "iuf":
        raise RecordingError(
            f"must hold numbers, got an array of dtype {array.dtype}", path=path, column=name
        )
    if array.ndim != 1:
        raise RecordingError(
            f"must be 1-D, got an array of shape {array.shape}", path=path, column=name
        )
    result = array.astype(np.float64, copy=True)
    result.setflags(write=False)
    return result


def _normalized_metadata(metadata: object, *, path: PathArg | None = None) -> dict[str, Any]:
    """A deep copy of ``metadata`` exactly as it reads back from a file (JSON)."""
    if not isinstance(metadata, Mapping):
        raise RecordingError(
            f"metadata must be a mapping, got {type(metadata).__name__}", path=path
        )
    try:
        text = json.dumps(dict(metadata), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise RecordingError(f"metadata is not JSON-serializable: {exc}", path=path) from exc
    result: dict[str, Any] = json.loads(text)
    return result


def _allowed_columns_text() -> str:
    return ", ".join(_COLUMNS)


# --------------------------------------------------------------------------- Recording


@dataclass(frozen=True, eq=False, repr=False)
class Recording:
    """A validated, immutable recording of DC-motor winding signals.

    Parameters
    ----------
    t : numpy.ndarray
        Sample times (s): at least 2, strictly increasing, uniformly sampled
        (every period within 1 % of the median period).
    signals : Mapping[str, numpy.ndarray]
        A non-empty subset of :data:`CHANNELS` mapped to 1-D arrays of the length
        of ``t``, in SI units (:data:`UNITS`); all values finite.
    metadata : Mapping[str, Any]
        Free-form JSON-serializable description (motor, seed, generator, ...).

    Notes
    -----
    The arrays are stored as read-only float64 copies and ``signals`` as a
    read-only mapping in :data:`CHANNELS` order. ``metadata`` is stored as a
    read-only mapping of a deep copy normalised through JSON (tuples become
    lists, keys strings), i.e. exactly as it reads back from a file.
    Two recordings are equal when all their arrays and metadata are equal.

    Raises
    ------
    RecordingError
        If any of the rules above is broken; rows are 1-based sample numbers.
    """

    t: np.ndarray
    signals: Mapping[str, np.ndarray]
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = _as_float_vector(self.t, _TIME)
        if not isinstance(self.signals, Mapping):
            raise RecordingError(
                f"signals must be a mapping of channel name to array, "
                f"got {type(self.signals).__name__}"
            )
        for name in self.signals:
            if name not in CHANNELS:
                raise RecordingError(
                    f"unknown channel {name!r}; allowed: {', '.join(CHANNELS)}", column=str(name)
                )
        if not self.signals:
            raise RecordingError(f"no signal channel; need at least one of {', '.join(CHANNELS)}")
        signals: dict[str, FloatArray] = {}
        for name in CHANNELS:
            if name in self.signals:
                values = _as_float_vector(self.signals[name], name)
                if values.size != t.size:
                    raise RecordingError(
                        f"has {values.size} samples but t has {t.size}", column=name
                    )
                signals[name] = values
        problem = _samples_problem(t, list(signals.items()))
        if problem is not None:
            _raise_problem(problem, None, _row_locator(0))
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "signals", MappingProxyType(signals))
        object.__setattr__(self, "metadata", MappingProxyType(_normalized_metadata(self.metadata)))

    # ------------------------------------------------------------------ properties

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.t.size)

    @cached_property
    def dt(self) -> float:
        """Sample period (s): the median of the differences of ``t``."""
        return float(np.median(np.diff(self.t)))

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate (Hz), ``1 / dt``."""
        return 1.0 / self.dt

    @property
    def duration_s(self) -> float:
        """Time covered (s), counting one period per sample: ``n_samples * dt``."""
        return self.n_samples * self.dt

    @property
    def channels(self) -> tuple[str, ...]:
        """Names of the channels present, in :data:`CHANNELS` order."""
        return tuple(self.signals)

    # ------------------------------------------------------------------ access

    def __getitem__(self, name: str) -> FloatArray:
        """The read-only array of ``"t"`` or of a channel.

        Raises
        ------
        KeyError
            If the recording has no such column.
        """
        if name == _TIME:
            return self.t
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(
                f"recording has no column {name!r}; it has {', '.join((_TIME, *self.channels))}"
            ) from None

    def has(self, *names: str) -> bool:
        """Whether every one of ``names`` (``"t"`` or channels) is present."""
        return all(name == _TIME or name in self.signals for name in names)

    def require(self, *names: str, path: PathArg | None = None, purpose: str | None = None) -> None:
        """Raise unless every one of ``names`` is present.

        Parameters
        ----------
        *names : str
            Required columns (``"t"`` or channels).
        path : str or os.PathLike, optional
            File named in the message.
        purpose : str, optional
            What the columns are needed for, e.g. ``"the field circuit"``.

        Raises
        ------
        RecordingError
            e.g. ``"run.csv: column 'vf': missing column 'vf' (needed for the
            field circuit); the recording has t, va, ia"``.
        ValueError
            If a name is not ``"t"`` or one of :data:`CHANNELS` (a programming error).
        """
        for name in names:
            if name not in _COLUMNS:
                raise ValueError(f"unknown column {name!r}; allowed: {_allowed_columns_text()}")
        missing = [name for name in names if not self.has(name)]
        if not missing:
            return
        listed = ", ".join(repr(name) for name in missing)
        text = f"missing column{'s' if len(missing) > 1 else ''} {listed}"
        if purpose:
            text += f" (needed for {purpose})"
        text += f"; the recording has {', '.join((_TIME, *self.channels))}"
        raise RecordingError(text, path=path, column=missing[0])

    def slice_time(self, t0: float, t1: float) -> Recording:
        """The samples with ``t0 <= t < t1`` (s), with the same channels and metadata.

        Raises
        ------
        RecordingError
            If fewer than 2 samples fall in the interval.
        """
        start = int(np.searchsorted(self.t, t0, side="left"))
        stop = int(np.searchsorted(self.t, t1, side="left"))
        count = max(0, stop - start)
        if count < _MIN_SAMPLES:
            raise RecordingError(
                f"slice [{t0:g}, {t1:g}) s holds {count} samples, fewer than {_MIN_SAMPLES} "
                f"(the recording spans {self.t[0]:g} to {self.t[-1]:g} s)"
            )
        return Recording(
            t=self.t[start:stop],
            signals={name: values[start:stop] for name, values in self.signals.items()},
            metadata=self.metadata,
        )

    def select(self, *names: str) -> Recording:
        """A recording with only the channels ``names`` (``"t"`` is accepted and ignored).

        Raises
        ------
        KeyError
            If a channel is absent.
        ValueError
            If no channel is named.
        """
        for name in names:
            if not self.has(name):
                raise KeyError(
                    f"recording has no channel {name!r}; it has {', '.join(self.channels)}"
                )
        chosen = {name: self.signals[name] for name in CHANNELS if name in names}
        if not chosen:
            raise ValueError(f"select() needs at least one channel of {', '.join(self.channels)}")
        return Recording(t=self.t, signals=chosen, metadata=self.metadata)

    # ------------------------------------------------------------------ dunder

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Recording):
            return NotImplemented
        return (
            self.channels == other.channels
            and np.array_equal(self.t, other.t)
            and all(np.array_equal(self.signals[c], other.signals[c]) for c in self.channels)
            and dict(self.metadata) == dict(other.metadata)
        )

    def __repr__(self) -> str:
        return (
            f"Recording(n_samples={self.n_samples}, sample_rate_hz={self.sample_rate_hz:.6g}, "
            f"t0={self.t[0]:.9g}, duration_s={self.duration_s:.6g}, channels={self.channels}, "
            f"metadata_keys={tuple(self.metadata)})"
        )

    def __reduce__(self) -> tuple[Any, ...]:
        # MappingProxyType cannot be pickled; rebuild (and re-validate) from plain dicts.
        return (Recording, (self.t, dict(self.signals), dict(self.metadata)))


# --------------------------------------------------------------------------- dispatch


def _format_of(path: PathArg) -> str:
    lower = os.fspath(path).lower()
    if lower.endswith((".csv", ".csv.gz")):
        return "csv"
    if lower.endswith(".mcap"):
        return "mcap"
    raise RecordingError(
        "unsupported file type: expected a name ending in .csv, .csv.gz or .mcap", path=path
    )


def read_recording(path: PathArg) -> Recording:
    """Read a recording, choosing the format by the file name.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.csv``, ``.csv.gz`` or ``.mcap`` file.

    Raises
    ------
    RecordingError
        For any other suffix, or when the file is unreadable or invalid.
    """
    if _format_of(path) == "csv":
        return read_csv(path)
    return read_mcap(path)


def write_recording(rec: Recording, path: PathArg, *, block_s: float = 0.1) -> None:
    """Write a recording, choosing the format by the file name.

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or os.PathLike
        A ``.csv``, ``.csv.gz`` or ``.mcap`` file; overwritten if it exists.
    block_s : float
        MCAP only: duration of the samples in one message (s).

    Raises
    ------
    RecordingError
        For any other suffix, or when the file cannot be written.
    """
    if _format_of(path) == "csv":
        write_csv(rec, path)
    else:
        write_mcap(rec, path, block_s=block_s)


# --------------------------------------------------------------------------- CSV


def _is_gzip_name(name: str) -> bool:
    return name.lower().endswith(".gz")


def _open_csv_text(name: str) -> IO[str]:
    # utf-8-sig drops the byte-order mark spreadsheet programs put in front of the header.
    if _is_gzip_name(name):
        return gzip.open(name, "rt", encoding="utf-8-sig")
    return open(name, encoding="utf-8-sig")


@contextmanager
def _translated_read_errors(name: str) -> Iterator[None]:
    """Turn I/O, gzip and decoding failures into one-line RecordingErrors."""
    try:
        yield
    except RecordingError:
        raise
    except gzip.BadGzipFile as exc:
        raise RecordingError(f"corrupt gzip file: {exc}", path=name) from exc
    except (EOFError, zlib.error) as exc:
        detail = str(exc) or type(exc).__name__
        raise RecordingError(f"corrupt gzip file: {detail}", path=name) from exc
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"not a UTF-8 text file (byte {exc.object[exc.start]:#04x} cannot be decoded)",
            path=name,
        ) from exc
    except OSError as exc:
        raise RecordingError(f"cannot read file: {exc.strerror or exc}", path=name) from exc


@dataclass(frozen=True)
class _CsvHeader:
    columns: tuple[str, ...]
    line: int  # 1-based line number of the header row
    metadata: dict[str, Any]


def _looks_numeric(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _reject_json_constant(constant: str) -> NoReturn:
    raise ValueError(f"{constant} is not valid JSON")


def _loads_strict(text: str | bytes) -> Any:
    """``json.loads`` without the non-standard NaN/Infinity constants."""
    return json.loads(text, parse_constant=_reject_json_constant)


def _parse_metadata_comment(text: str, name: str, line: int) -> dict[str, Any]:
    payload = text[len(_METADATA_PREFIX) :].strip()
    try:
        metadata = _loads_strict(payload)
    except ValueError as exc:
        raise RecordingError(
            f"metadata comment is not valid JSON: {exc}", path=name, row=line
        ) from exc
    if not isinstance(metadata, dict):
        raise RecordingError(
            f"metadata comment must hold a JSON object, got {type(metadata).__name__}",
            path=name,
            row=line,
        )
    return metadata


def _check_csv_header(columns: Sequence[str], name: str, line: int) -> None:
    if all(columns) and all(_looks_numeric(column) for column in columns):
        raise RecordingError(
            "no header row: the first row holds numbers; expected column names such as t,va,ia",
            path=name,
            row=line,
        )
    seen: dict[str, int] = {}
    for position, column in enumerate(columns, start=1):
        if not column:
            raise RecordingError(f"empty column name in field {position}", path=name, row=line)
        if column not in _COLUMNS:
            hint = f" (did you mean {column.lower()!r}?)" if column.lower() in _COLUMNS else ""
            raise RecordingError(
                f"unknown column {column!r}{hint}; allowed: {_allowed_columns_text()}",
                path=name,
                row=line,
                column=column,
            )
        if column in seen:
            raise RecordingError(
                f"duplicate column {column!r} (fields {seen[column]} and {position})",
                path=name,
                row=line,
                column=column,
            )
        seen[column] = position
    if _TIME not in seen:
        raise RecordingError(
            f"no 't' column (time, s) in the header; columns found: {', '.join(columns)}",
            path=name,
            row=line,
        )
    if len(seen) < 2:
        raise RecordingError(
            f"no signal column; need at least one of {', '.join(CHANNELS)}", path=name, row=line
        )


def _read_csv_header(stream: IO[str], name: str) -> _CsvHeader:
    """Read comment lines and the header row, leaving ``stream`` at the first data row."""
    line = 0
    metadata: dict[str, Any] | None = None
    metadata_line = 0
    while True:
        text = stream.readline()
        if not text:
            if line == 0:
                raise RecordingError("file is empty", path=name)
            raise RecordingError(
                "no header row: the file holds only comments or blank lines", path=name
            )
        line += 1
        stripped = text.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if stripped.startswith(_METADATA_PREFIX):
                if metadata is not None:
                    raise RecordingError(
                        f"second metadata comment (the first is on row {metadata_line})",
                        path=name,
                        row=line,
                    )
                metadata = _parse_metadata_comment(stripped, name, line)
                metadata_line = line
            continue
        try:
            fields = next(csv.reader([text]))
        except csv.Error as exc:
            raise RecordingError(f"unreadable header row: {exc}", path=name, row=line) from exc
        columns = tuple(column.strip() for column in fields)
        _check_csv_header(columns, name, line)
        return _CsvHeader(columns, line, metadata or {})


def _load_csv_fast(stream: IO[str], n_columns: int) -> FloatArray | None:
    """All data rows at C speed, or None when anything is off (the exact path says what)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
        try:
            table = np.loadtxt(
                stream,
                delimiter=",",
                comments=None,
                quotechar=None,
                dtype=np.float64,
                ndmin=2,
            )
        except UnicodeDecodeError:
            raise
        except ValueError:
            return None
    if table.shape[0] > 0 and table.shape[1] != n_columns:
        return None
    return table.reshape(-1, n_columns)


def _parse_cell(cell: str, name: str, line: int, column: str) -> float:
    text = cell.strip()
    if not text:
        raise RecordingError("empty cell", path=name, row=line, column=column)
    try:
        if "_" in text:  # float() accepts digit separators; a CSV number never has them
            raise ValueError(text)
        return float(text)
    except ValueError:
        raise RecordingError(
            f"non-numeric value {cell!r}", path=name, row=line, column=column
        ) from None


def _load_csv_exact(
    stream: IO[str], header: _CsvHeader, name: str
) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """All data rows and their line numbers, raising at the first malformed cell."""
    n_columns = len(header.columns)
    rows: list[list[float]] = []
    lines: list[int] = []
    reader = csv.reader(stream, quoting=csv.QUOTE_NONE)
    try:
        for fields in reader:
            line = header.line + reader.line_num
            if not fields:  # blank line
                continue
            if len(fields) != n_columns:
                raise RecordingError(
                    f"expected {n_columns} fields ({','.join(header.columns)}), "
                    f"found {len(fields)}",
                    path=name,
                    row=line,
                )
            rows.append(
                [
                    _parse_cell(cell, name, line, col)
                    for cell, col in zip(fields, header.columns, strict=True)
                ]
            )
            lines.append(line)
    except csv.Error as exc:
        raise RecordingError(
            f"unreadable row: {exc}", path=name, row=header.line + reader.line_num
        ) from exc
    table = np.array(rows, dtype=np.float64).reshape(-1, n_columns)
    return table, np.array(lines, dtype=np.int64)


def _table_problem(table: FloatArray, columns: Sequence[str]) -> _Problem | None:
    position = {column: j for j, column in enumerate(columns)}
    in_file_order = [(column, table[:, j]) for j, column in enumerate(columns)]
    t = table[:, position[_TIME]]
    if t.size < _MIN_SAMPLES:
        return _Problem(f"fewer than {_MIN_SAMPLES} samples (found {t.size})")
    nonfinite = _first_nonfinite(in_file_order)
    if nonfinite is not None:
        return nonfinite
    return _timebase_problem(t, _DEFAULT_REL_TOL)


def read_csv(path: PathArg) -> Recording:
    """Read a CSV recording (gzip-compressed when the name ends in ``.gz``).

    Parameters
    ----------
    path : str or os.PathLike
        The file: a header row with ``t`` and at least one channel, then one row
        per sample; ``#`` comment lines may precede the header, one of them
        ``# dcobserver-metadata: {json}``. Blank lines are skipped.

    Returns
    -------
    Recording

    Raises
    ------
    RecordingError
        Naming the line number (1-based, counting every line of the file) and
        column of the first problem.
    """
    name = os.fspath(path)
    with _translated_read_errors(name):
        with _open_csv_text(name) as stream:
            header = _read_csv_header(stream, name)
            table = _load_csv_fast(stream, len(header.columns))
        problem = None if table is None else _table_problem(table, header.columns)
        if table is None or problem is not None:
            if problem is not None and problem.index is None:
                _raise_problem(problem, name, _row_locator(header.line))
            # Slow path: re-parse cell by cell to report the exact line and column.
            with _open_csv_text(name) as stream:
                for _ in range(header.line):
                    stream.readline()
                table, lines = _load_csv_exact(stream, header, name)
            problem = _table_problem(table, header.columns)
            if problem is not None:
                _raise_problem(problem, name, lambda index: _Location(row=int(lines[index])))
    position = {column: j for j, column in enumerate(header.columns)}
    return Recording(
        t=table[:, position[_TIME]],
        signals={c: table[:, position[c]] for c in CHANNELS if c in position},
        metadata=header.metadata,
    )


def _open_csv_for_writing(name: str) -> IO[str]:
    if _is_gzip_name(name):
        # mtime=0: the same recording always compresses to the same bytes.
        binary = gzip.GzipFile(name, "wb", compresslevel=_GZIP_LEVEL, mtime=0)
        return io.TextIOWrapper(binary, encoding="utf-8", newline="\n")
    return open(name, "w", encoding="utf-8", newline="\n")


def write_csv(rec: Recording, path: PathArg) -> None:
    """Write a recording as CSV (gzip-compressed when the name ends in ``.gz``).

    Columns are ``t`` then the channels in :data:`CHANNELS` order; numbers are
    written with ``repr``, so reading the file back gives identical float64
    values. Non-empty metadata is written as a ``# dcobserver-metadata:`` comment.

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or os.PathLike
        Destination; overwritten if it exists.

    Raises
    ------
    RecordingError
        If the file cannot be written.
    """
    name = os.fspath(path)
    columns = (_TIME, *rec.channels)
    arrays = [rec[column] for column in columns]
    try:
        with _open_csv_for_writing(name) as stream:
            if rec.metadata:
                stream.write(f"{_METADATA_PREFIX} {json.dumps(dict(rec.metadata))}\n")
            stream.write(",".join(columns) + "\n")
            for start in range(0, rec.n_samples, _CSV_WRITE_ROWS):
                stop = start + _CSV_WRITE_ROWS
                cells = [map(repr, array[start:stop].tolist()) for array in arrays]
                stream.write("\n".join(map(",".join, zip(*cells, strict=True))))
                stream.write("\n")
    except OSError as exc:
        raise RecordingError(f"cannot write file: {exc.strerror or exc}", path=name) from exc


# --------------------------------------------------------------------------- MCAP messages


class _SampleBlockError(ValueError):
    """A malformed sample block; ``column`` names the field concerned, if any."""

    def __init__(self, text: str, column: str | None = None) -> None:
        super().__init__(text)
        self.column = column


def sample_block_message(t_ns: npt.ArrayLike, signals: Mapping[str, npt.ArrayLike]) -> bytes:
    """Encode one block of samples as the JSON message of :data:`SAMPLES_TOPIC`.

    Parameters
    ----------
    t_ns : array_like of int
        Sample times, integer nanoseconds; non-empty, 1-D.
    signals : Mapping[str, array_like]
        Channels (a non-empty subset of :data:`CHANNELS`) to arrays of the
        length of ``t_ns``; finite values only (JSON has no NaN).

    Returns
    -------
    bytes
        UTF-8 JSON ``{"t_ns": [...], "va": [...], ...}``, channels in
        :data:`CHANNELS` order, floats in shortest round-trip form.

    Raises
    ------
    ValueError
        If the inputs break any of the rules above.
    """
    times = np.asarray(t_ns)
    if times.ndim != 1 or times.size == 0:
        raise ValueError(f"t_ns must be a non-empty 1-D array, got shape {times.shape}")
    if times.dtype.kind not in "iu":
        raise ValueError(f"t_ns must hold integer nanoseconds, got dtype {times.dtype}")
    unknown = [name for name in signals if name not in CHANNELS]
    if unknown:
        raise ValueError(f"unknown channel {unknown[0]!r}; allowed: {', '.join(CHANNELS)}")
    if not signals:
        raise ValueError(f"a sample block needs at least one of {', '.join(CHANNELS)}")
    block: dict[str, list[Any]] = {"t_ns": times.tolist()}
    for name in CHANNELS:
        if name not in signals:
            continue
        values = np.asarray(signals[name])
        if values.dtype.kind not in "iuf":
            raise ValueError(f"{name!r} must hold numbers, got dtype {values.dtype}")
        if values.shape != times.shape:
            raise ValueError(f"{name!r} has shape {values.shape} but t_ns has {times.shape}")
        bad = ~np.isfinite(values)
        if bad.any():
            index = int(np.argmax(bad))
            raise ValueError(f"{name!r}[{index}] is {values[index]}; JSON cannot carry it")
        block[name] = values.astype(np.float64).tolist()
    return json.dumps(block, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _block_array(value: object, name: str, *, integer: bool) -> npt.NDArray[Any]:
    if not isinstance(value, list):
        raise _SampleBlockError(f"{name!r} must be a JSON array", name)
    if not value:
        raise _SampleBlockError(f"{name!r} is empty", name)
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        raise _SampleBlockError(f"{name!r} must be a flat array of numbers", name) from None
    if array.ndim != 1:
        raise _SampleBlockError(f"{name!r} must be a flat array of numbers", name)
    if integer:
        if array.dtype.kind not in "iu":
            raise _SampleBlockError(f"{name!r} must hold integer nanoseconds", name)
        if array.dtype.kind == "u" and int(array.max()) > np.iinfo(np.int64).max:
            raise _SampleBlockError(f"{name!r} holds a time beyond the int64 range", name)
        return array.astype(np.int64)
    if array.dtype.kind not in "iuf":
        raise _SampleBlockError(f"{name!r} must hold numbers", name)
    return array.astype(np.float64)


def parse_sample_block(data: bytes) -> tuple[IntArray, dict[str, FloatArray]]:
    """Decode one :data:`SAMPLES_TOPIC` message (inverse of :func:`sample_block_message`).

    Parameters
    ----------
    data : bytes
        The UTF-8 JSON message.

    Returns
    -------
    t_ns : numpy.ndarray of int64
        Sample times, integer nanoseconds.
    signals : dict[str, numpy.ndarray of float64]
        The channels present, in :data:`CHANNELS` order. Non-finite values
        written as the non-standard ``NaN``/``Infinity`` are passed through, for
        the caller's validation to report with their location.

    Raises
    ------
    ValueError
        If the message is not JSON, not an object, has unknown fields, lacks
        ``t_ns`` or every channel, or holds arrays of unequal length.
    """
    try:
        block = json.loads(data)
    except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError
        raise _SampleBlockError(f"not valid JSON: {exc}") from None
    if not isinstance(block, dict):
        raise _SampleBlockError(f"expected a JSON object, got {type(block).__name__}")
    for key in block:
        if key != "t_ns" and key not in CHANNELS:
            raise _SampleBlockError(
                f"unknown field {key!r}; allowed: t_ns, {', '.join(CHANNELS)}", key
            )
    if "t_ns" not in block:
        raise _SampleBlockError("missing field 't_ns'", "t_ns")
    t_ns = _block_array(block["t_ns"], "t_ns", integer=True)
    signals: dict[str, FloatArray] = {}
    for name in CHANNELS:
        if name in block:
            values = _block_array(block[name], name, integer=False)
            if values.size != t_ns.size:
                raise _SampleBlockError(
                    f"signals of unequal length: {name!r} has {values.size} samples "
                    f"but 't_ns' has {t_ns.size}",
                    name,
                )
            signals[name] = values
    if not signals:
        raise _SampleBlockError(f"no signal field; need at least one of {', '.join(CHANNELS)}")
    return t_ns, signals


# --------------------------------------------------------------------------- MCAP files


def write_mcap(rec: Recording, path: PathArg, *, block_s: float = 0.1) -> None:
    """Write a recording as MCAP.

    One JSON message on :data:`SAMPLES_TOPIC` per block of ``block_s`` seconds
    (schema :data:`SAMPLES_SCHEMA_NAME`, encoding ``jsonschema``), log and
    publish time the block's first ``t_ns``; the metadata in a Metadata record
    :data:`METADATA_NAME` as ``{"json": ...}``; ZSTD-compressed chunks.

    Parameters
    ----------
    rec : Recording
        The recording; its times must be >= 0 (MCAP log times are unsigned).
    path : str or os.PathLike
        Destination; overwritten if it exists.
    block_s : float
        Duration of the samples in one message (s); at least one sample per message.

    Raises
    ------
    RecordingError
        If the times cannot be stored or the file cannot be written.
    ValueError
        If ``block_s`` is not a positive finite number.
    """
    if not (math.isfinite(block_s) and block_s > 0):
        raise ValueError(f"block_s must be a positive number of seconds, got {block_s!r}")
    name = os.fspath(path)
    if rec.t[0] < 0 or rec.t[-1] * _NS_PER_S >= 2.0**63:
        raise RecordingError(
            f"times {rec.t[0]:g} to {rec.t[-1]:g} s cannot be stored as MCAP log times "
            f"(unsigned 64-bit nanoseconds): shift t to start at or after 0",
            path=name,
            column=_TIME,
        )
    t_ns = np.rint(rec.t * _NS_PER_S).astype(np.int64)
    if not (np.diff(t_ns) > 0).all():
        raise RecordingError(
            "sample period below 1 ns cannot be stored in MCAP", path=name, column=_TIME
        )
    per_block = max(1, round(block_s / rec.dt))
    try:
        with open(name, "wb") as stream:
            writer = Writer(stream, chunk_size=_MCAP_CHUNK_SIZE, compression=CompressionType.ZSTD)
            writer.start()
            schema_id = writer.register_schema(
                name=SAMPLES_SCHEMA_NAME,
                encoding="jsonschema",
                data=json.dumps(SAMPLE_BLOCK_SCHEMA).encode("utf-8"),
            )
            channel_id = writer.register_channel(
                topic=SAMPLES_TOPIC, message_encoding="json", schema_id=schema_id
            )
            writer.add_metadata(METADATA_NAME, {"json": json.dumps(dict(rec.metadata))})
            for start in range(0, rec.n_samples, per_block):
                stop = start + per_block
                block_t_ns = t_ns[start:stop]
                data = sample_block_message(
                    block_t_ns, {c: rec.signals[c][start:stop] for c in rec.channels}
                )
                log_time = int(block_t_ns[0])
                writer.add_message(
                    channel_id=channel_id, log_time=log_time, data=data, publish_time=log_time
                )
            writer.finish()
    except OSError as exc:
        raise RecordingError(f"cannot write file: {exc.strerror or exc}", path=name) from exc


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


def _scan_mcap_indexed(stream: IO[bytes]) -> _McapContent:
    """Read a finished file through its summary section."""
    reader = make_reader(stream)
    content = _McapContent()
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
    if stream.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
        raise RecordingError("not an MCAP file (no MCAP magic bytes at the start)", path=name)
    finished = False
    if size >= 2 * len(_MCAP_MAGIC):
        stream.seek(-len(_MCAP_MAGIC), os.SEEK_END)
        finished = stream.read() == _MCAP_MAGIC
    if finished:
        stream.seek(0)
        try:
            return _scan_mcap_indexed(stream)
        except Exception as exc:
            # A damaged summary or chunk: read what precedes the damage instead.
            _log.debug("%s: indexed MCAP read failed (%s); streaming instead", name, exc)
    stream.seek(0)
    return _scan_mcap_streaming(stream, size)


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


def read_mcap(path: PathArg) -> Recording:
    """Read an MCAP recording.

    The messages on :data:`SAMPLES_TOPIC` are concatenated in file order and
    validated as a whole; other topics are ignored. A file whose writer never
    called ``finish()`` or that was cut short is read up to the last complete
    chunk (a warning is logged).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mcap`` file.

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
    if not content.complete:
        _log.warning(
            "%s: MCAP file is unfinished or cut short (%s); using the %d complete sample "
            "blocks before the cut",
            name,
            content.cut_reason,
            len(content.blocks),
        )
    metadata = _mcap_metadata(content.metadata, name)
    if not content.blocks:
        cut = " before the point where the file is cut" if not content.complete else ""
        raise RecordingError(f"no messages on topic {SAMPLES_TOPIC!r}{cut}", path=name)

    times: list[IntArray] = []
    columns: dict[str, list[FloatArray]] = {}
    for index, raw in enumerate(content.blocks, start=1):
        where = _message_where(index, raw.log_time)
        if raw.message_encoding != "json":
            raise RecordingError(
                f"message encoding {raw.message_encoding!r}, expected 'json'",
                path=name,
                where=where,
                message_index=index,
            )
        try:
            t_ns, signals = parse_sample_block(raw.data)
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

    sizes = np.array([block.size for block in times], dtype=np.int64)
    starts = np.concatenate(([0], np.cumsum(sizes)[:-1]))
    log_times = [raw.log_time for raw in content.blocks]
    t = np.concatenate(times) / _NS_PER_S
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
    return Recording(t=t, signals=signal_arrays, metadata=metadata)
