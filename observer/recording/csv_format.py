"""CSV recordings (``.csv``, or gzip-compressed ``.csv.gz``).

A header row naming the columns (``t`` plus at least one channel, in any
order), then one row per sample. Lines starting with ``#`` before the header
are comments; the recording's metadata is kept in one of them as
``# dcobserver-metadata: {json}``. Numbers are written with ``repr``, so a
round trip reproduces every float64 exactly. Problems are reported with the
1-based line number in the file and the column.
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import os
import warnings
import zlib
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import IO, Any, Final

import numpy as np
import numpy.typing as npt

from observer.recording.atomic import AtomicFile
from observer.recording.base import (
    _COLUMNS,
    _DEFAULT_REL_TOL,
    _MIN_SAMPLES,
    _TIME,
    CHANNELS,
    FloatArray,
    PathArg,
    Recording,
    RecordingError,
    _allowed_columns_text,
    _first_nonfinite,
    _loads_strict,
    _Location,
    _Problem,
    _raise_problem,
    _row_locator,
    _timebase_problem,
)

_METADATA_PREFIX: Final = "# dcobserver-metadata:"
_CSV_WRITE_ROWS: Final = 65536
_GZIP_LEVEL: Final = 6


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


_SEPARATORS: Final = {";": "semicolons", "\t": "tabs", "|": "vertical bars"}


def _check_csv_header(columns: Sequence[str], name: str, line: int) -> None:
    if len(columns) == 1:
        for separator, called in _SEPARATORS.items():
            if separator in columns[0]:
                raise RecordingError(
                    f"the header's fields are separated by {called}, not commas: save the file "
                    "as comma-separated values (',' between fields, '.' as decimal point)",
                    path=name,
                    row=line,
                )
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
        if any(ord(c) < 32 and c not in "\t\r\n" for c in text):
            raise RecordingError("not a CSV text file: binary data", path=name, row=line)
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


_GZIP_MAGIC: Final = b"\x1f\x8b"
_MCAP_MAGIC: Final = b"\x89MCAP0\r\n"


def _check_content_kind(name: str) -> None:
    """A file whose bytes are not what its name says: a one-line error saying what it is."""
    try:
        with open(name, "rb") as f:
            head = f.read(len(_MCAP_MAGIC))
    except OSError:
        return  # reported, with its reason, when the file is opened to be read
    if not head:
        return
    is_gzip, is_mcap = head.startswith(_GZIP_MAGIC), head.startswith(_MCAP_MAGIC)
    if is_mcap:
        raise RecordingError("this is an MCAP file, not CSV: name it .mcap", path=name)
    if _is_gzip_name(name) and not is_gzip:
        raise RecordingError(
            "not gzip-compressed (no gzip header): name it .csv if it is plain text", path=name
        )
    if not _is_gzip_name(name) and is_gzip:
        raise RecordingError("gzip-compressed data: name the file .csv.gz", path=name)


def _gzip_corruption(name: str) -> str | None:
    """Why the gzip stream of ``name`` is corrupt (its CRC, its end), or None if intact."""
    try:
        with gzip.open(name, "rb") as f:
            while f.read(1 << 20):
                pass
    except (gzip.BadGzipFile, EOFError, zlib.error) as exc:
        return str(exc) or type(exc).__name__
    except OSError:
        return None  # not the stream's fault (missing, unreadable): reported as such
    return None


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
    _check_content_kind(name)
    try:
        return _read_csv(name)
    except RecordingError:
        # A damaged gzip stream decompresses to garbage before its CRC is reached:
        # the garbage is not the problem, the file is.
        corruption = _gzip_corruption(name) if _is_gzip_name(name) else None
        if corruption is not None:
            raise RecordingError(f"corrupt gzip file: {corruption}", path=name) from None
        raise


def _read_csv(name: str) -> Recording:
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


@contextmanager
def _csv_text_writer(name: str, out: IO[bytes]) -> Iterator[IO[str]]:
    """A UTF-8 text stream into ``out`` (gzip-compressed for ``.gz``), leaving ``out`` open."""
    gz = None
    if _is_gzip_name(name):
        # mtime=0 and the final name in the header (not the temporary one): the same
        # recording always compresses to the same bytes.
        gz = gzip.GzipFile(name, "wb", compresslevel=_GZIP_LEVEL, fileobj=out, mtime=0)
    text = io.TextIOWrapper(gz if gz is not None else out, encoding="utf-8", newline="\n")
    try:
        yield text
        text.flush()
    finally:
        text.detach()
        if gz is not None:
            gz.close()  # writes the gzip trailer; closes only what it opened, not ``out``


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
        Destination; replaced only once the new file is complete
        (:mod:`observer.recording.atomic`).

    Raises
    ------
    RecordingError
        If the file cannot be written.
    """
    name = os.fspath(path)
    columns = (_TIME, *rec.channels)
    arrays = [rec[column] for column in columns]
    try:
        with AtomicFile(name) as out, _csv_text_writer(name, out.stream) as stream:
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
