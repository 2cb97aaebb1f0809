"""Many recordings at once: ``replay`` and ``diagnose`` over a fleet's archive.

Not a command (it is not in :data:`observer.cli.COMMANDS`): what ``replay`` and
``diagnose`` share when given several files, a folder or a glob. Each file is
one task that runs the single-file command's own code (so a row is what that
command reports for the file); the tasks run

- in this process, one after the other (``--workers 1``, one file, or dask not
  installed: a warning says so);
- on a ``distributed.LocalCluster`` of ``--workers`` processes on this machine
  (the default: one per core);
- on an existing Dask cluster (``--scheduler tcp://host:port``), whose workers
  have dcobserver installed and see the files at the same paths.

A file that cannot be read (corrupt, not a recording, too short) becomes one
row naming it with its ``error``, and one line in the summary; the other files'
rows are kept. The table goes to ``--table`` (CSV, or Parquet for ``.parquet``
with pyarrow) or, without it, as CSV to stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import glob
import io
import json
import logging
import os
import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

#: The optional dependencies' extra: ``pip install 'dcobserver[fleet]'``.
EXTRA = "dcobserver[fleet]"
#: The files a folder given as input contributes (searched recursively).
RECORDING_SUFFIXES = (".mcap", ".csv", ".csv.gz")
#: The first columns of every table, in this order.
ID_COLUMNS = ("file", "drive_id", "motor_id", "error")
#: Seconds to reach a ``--scheduler`` before giving up.
CONNECT_TIMEOUT_S = 10.0
#: The variable dask's nannies set in their workers that slows the estimator down.
MALLOC_TRIM = "MALLOC_TRIM_THRESHOLD_"


@dataclass(frozen=True)
class FileResult:
    """What one file gave: its rows, its warnings, or why it gave none.

    Attributes
    ----------
    path : str
        The file as the user named it (or as a folder or glob expanded).
    rows : tuple of dict
        Table rows (column -> value), without the ``file`` column.
    warnings : tuple of str
        One line each, naming the file (plausibility findings, a cut MCAP, ...).
    error : str
        Why the file gave no rows ("" if it was read); one line.
    """

    path: str
    rows: tuple[dict[str, Any], ...] = ()
    warnings: tuple[str, ...] = ()
    error: str = ""


#: A file's work: ``fn(path, options) -> (rows, warnings)``; a module-level function,
#: so that Dask can send it to its workers by name.
FileWork = Callable[[str, Any], tuple[list[dict[str, Any]], list[str]]]


def add_options(parser: argparse.ArgumentParser, what: str) -> None:
    """``--table``, ``--workers`` and ``--scheduler`` of a command that takes many files.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    what : str
        What one row of the table is, for the help text ("every window's estimate").
    """
    group = parser.add_argument_group(
        "many recordings (several files, a folder, a glob)",
        f"One table of {what}, per drive and motor (ids from each log's metadata, else "
        "the config's), a row naming each file that cannot be read (column 'error'). "
        "Folders are searched recursively for .mcap, .csv and .csv.gz; quote a glob "
        "('logs/**/*.mcap') to let dcobserver expand it. Parallel by dask.distributed "
        f"(pip install '{EXTRA}'; without it the files run one after the other). Exit "
        "status 1 when some files could not be read (their rows say why).",
    )
    group.add_argument(
        "--table", metavar="OUT.csv|OUT.parquet", default=None,
        help="write the table here (.parquet needs pyarrow); default: CSV on stdout",
    )  # fmt: skip
    group.add_argument(
        "--workers", type=_positive_int, default=None, metavar="N",
        help="worker processes of a Dask LocalCluster on this machine (default: one per "
        "core, at most one per file; 1: in this process, no dask needed)",
    )  # fmt: skip
    group.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", default=None,
        help="run on this existing Dask cluster instead (its workers need dcobserver and "
        "the files at the same paths)",
    )  # fmt: skip


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"an integer >= 1, got {value}")
    return value


def _is_glob(spec: str) -> bool:
    return any(c in spec for c in "*?[")


def wants_table(args: argparse.Namespace) -> bool:
    """Whether the command runs over many recordings (and writes a table)."""
    specs: Sequence[str] = args.recording
    return (
        len(specs) > 1
        or args.table is not None
        or args.scheduler is not None
        or args.workers is not None
        or any(os.path.isdir(s) or (_is_glob(s) and not os.path.exists(s)) for s in specs)
    )


def _is_recording_name(path: Path) -> bool:
    from observer.recording import is_temporary

    name = path.name.lower()
    return name.endswith(RECORDING_SUFFIXES) and not is_temporary(path)


def expand(specs: Sequence[str]) -> list[str]:
    """The recordings named by files, folders and glob patterns, each once, in order.

    A folder gives its ``.mcap``, ``.csv`` and ``.csv.gz`` files (recursively, sorted,
    no temporary files of a write in progress); a glob every file it matches (``**``
    recursive); a file itself, whatever its name.

    Raises
    ------
    observer.cli.UserError
        For a spec that names nothing: ``"logs/*.mcap: no file matches"``.
    """
    from observer.cli import UserError
    from observer.commands.outputs import check_input

    found: list[str] = []
    for spec in specs:
        if os.path.isdir(spec):
            files = sorted(
                str(p) for p in Path(spec).rglob("*") if p.is_file() and _is_recording_name(p)
            )
            if not files:
                raise UserError(
                    f"{spec}: a directory, not a file, and no recording "
                    "(.mcap, .csv, .csv.gz) in it"
                )
        elif _is_glob(spec) and not os.path.exists(spec):
            files = sorted(p for p in glob.glob(spec, recursive=True) if os.path.isfile(p))
            if not files:
                raise UserError(f"{spec}: no file matches")
        else:
            check_input(spec)
            files = [spec]
        found.extend(files)
    seen: set[str] = set()
    unique = []
    for path in found:
        key = os.path.realpath(path)
        if key not in seen:
            seen.add(key)
            unique.append(path)
    return unique


def check_table_output(table: str | None, inputs: Sequence[str]) -> None:
    """A one-line error before the work if ``--table`` cannot be written.

    Raises
    ------
    observer.cli.UserError
        Unwritable path, an input's own name, an unknown suffix, ``.parquet``
        without pyarrow.
    """
    from observer.cli import UserError
    from observer.commands.outputs import check_outputs

    if table is None:
        return
    suffix = table.lower()
    if suffix.endswith(".parquet"):
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise UserError(
                f"--table {table}: Parquet needs pyarrow, which is not installed: "
                f"pip install '{EXTRA}' (or name the table .csv)"
            ) from None
    elif not suffix.endswith(".csv"):
        raise UserError(f"--table {table}: name it .csv or .parquet")
    check_outputs(("--table", table), inputs=inputs)


def flatten(value: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one level of dotted keys; lists as compact JSON text.

    ``flatten({"field": {"R": 1.0, "std": {"R": 0.1}}, "flags": []})`` is
    ``{"field.R": 1.0, "field.std.R": 0.1, "flags": "[]"}``; NaN and infinities
    become None (as in the commands' JSON).
    """
    from observer.commands.display import finite_json

    out: dict[str, Any] = {}
    for key, item in value.items():
        name = f"{prefix}{key}"
        if isinstance(item, Mapping):
            out.update(flatten(item, f"{name}."))
        elif isinstance(item, list | tuple):
            out[name] = json.dumps(finite_json(item), separators=(",", ":"))
        else:
            out[name] = finite_json(item)
    return out


def recording_ids(path: str, config: Any, metadata: Mapping[str, Any] | None = None) -> dict:
    """``drive_id`` and ``motor_id`` of a recording: its metadata's, else the config's.

    The daemon writes both into every log's metadata; a simulated or foreign
    recording has neither and takes ``[observer] drive_id`` and ``motor_id``.
    ``metadata`` is the recording's if already read (else read from an MCAP's
    start; a CSV's is read whole).
    """
    if metadata is None:
        metadata = _metadata(path)
    drive = metadata.get("drive_id")
    motor = metadata.get("motor_id")
    return {
        "drive_id": drive if isinstance(drive, str) and drive else config.observer.drive_id,
        "motor_id": motor if isinstance(motor, str) and motor else config.observer.motor_id,
    }


def _metadata(path: str) -> Mapping[str, Any]:
    """The recording metadata of a file ({} if it has none or cannot say)."""
    from observer.recording import RecordingError, final_path, read_recording

    if final_path(path).name.lower().endswith(".mcap"):
        return mcap_metadata(path)
    try:
        return read_recording(path).metadata
    except (RecordingError, OSError):
        return {}


def mcap_metadata(path: str) -> Mapping[str, Any]:
    """The recording metadata at the start of an MCAP file, read without its samples
    ({} if it has none before the first message, or cannot be read)."""
    from mcap.records import Message, Metadata

    from observer.recording import METADATA_NAME, McapRecordStream

    try:
        with open(path, "rb") as stream:
            for record in McapRecordStream(stream, os.path.getsize(path)):
                if isinstance(record, Metadata) and record.name == METADATA_NAME:
                    found = json.loads(record.metadata.get("json", "{}"))
                    return found if isinstance(found, dict) else {}
                if isinstance(record, Message):  # writers put the metadata first
                    return {}
    except (OSError, ValueError):
        pass
    return {}


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())


@contextlib.contextmanager
def _collected_warnings() -> Iterator[list[str]]:
    """The log's warnings during the block, collected instead of printed.

    In a worker process nobody would see them; in this process the summary
    prints them with the file's other warnings, once.
    """
    root = logging.getLogger()
    collect = _Collect()
    saved = root.handlers[:]
    root.handlers[:] = [collect]
    try:
        yield collect.lines
    finally:
        root.handlers[:] = saved


def _error_text(exc: BaseException) -> str:
    from observer.cli import _user_error_types

    if isinstance(exc, _user_error_types()):
        return str(exc)
    from drivers.base import SourceError

    if isinstance(exc, SourceError):
        return str(exc)
    if isinstance(exc, OSError):
        return f"cannot read: {exc.strerror or exc}"
    if isinstance(exc, MemoryError):
        return "out of memory"
    # A file the readers did not foresee (a corrupt compressed chunk, ...): one line
    # naming what failed, so that one file cannot end the run over the others.
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def run_one(work: FileWork, path: str, options: Any) -> FileResult:
    """``work(path, options)`` with its failure turned into the file's ``error``.

    Runs in a Dask worker or in this process; never raises for a bad file.
    """
    import warnings

    with _collected_warnings() as logged, warnings.catch_warnings():
        # As the CLI does: numpy's notes on NaN along the way are not the user's.
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            rows, found = work(path, options)
        except Exception as exc:
            return FileResult(path, warnings=tuple(logged), error=_error_text(exc))
    return FileResult(path, rows=tuple(rows), warnings=tuple(logged + found))


def _default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def run_files(
    command: str,
    work: FileWork,
    paths: Sequence[str],
    options: Any,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
) -> list[FileResult]:
    """Every file's :class:`FileResult`, in the order of ``paths``.

    Parameters
    ----------
    command : str
        The command's name, for messages and the progress bar.
    work : callable
        ``work(path, options) -> (rows, warnings)``, module-level (Dask pickles it
        by name); raises for a file it cannot use.
    paths : sequence of str
    options : Any
        Passed to every call (picklable).
    workers : int, optional
        Processes on this machine (default: one per core, at most one per file).
    scheduler : str, optional
        Address of a running Dask scheduler; overrides ``workers``.
    progress : bool
        Show a progress bar (files done) on stderr.

    Raises
    ------
    observer.cli.UserError
        ``--scheduler`` without dask installed, or a scheduler that cannot be reached.
    """
    from tqdm import tqdm

    from observer.cli import UserError
    from observer.commands.display import print_warnings

    local = min(workers or _default_workers(), len(paths))
    client_factory: Callable[[], contextlib.AbstractContextManager[Any]] | None = None
    if scheduler is not None or local > 1:
        try:
            import distributed
        except ImportError:
            if scheduler is not None:
                raise UserError(
                    f"--scheduler needs dask.distributed, which is not installed: "
                    f"pip install '{EXTRA}'"
                ) from None
            print_warnings(command, [
                f"dask.distributed is not installed: the {len(paths)} files run one after "
                f"the other in this process (pip install '{EXTRA}' for {local} at once)"
            ])  # fmt: skip
        else:
            client_factory = (
                (lambda: _remote_client(distributed, scheduler, command))
                if scheduler is not None
                else (lambda: _local_client(distributed, local))
            )
    absolute = [os.path.abspath(p) for p in paths]
    results: list[FileResult | None] = [None] * len(paths)
    with contextlib.ExitStack() as stack:
        # Connected (or the cluster started) before the bar: a failure is one line alone.
        client = stack.enter_context(client_factory()) if client_factory is not None else None
        bar = stack.enter_context(
            tqdm(total=len(paths), unit="file", desc=command, disable=not progress, file=sys.stderr)
        )
        if client is None:
            for i, path in enumerate(absolute):
                results[i] = run_one(work, path, options)
                bar.update(1)
        else:
            from distributed import as_completed

            futures = {
                client.submit(run_one, work, path, options, pure=False): i
                for i, path in enumerate(absolute)
            }
            for future in as_completed(futures):
                i = futures[future]
                try:
                    results[i] = future.result()
                except Exception as exc:  # the worker died under it, or lost it
                    results[i] = FileResult(paths[i], error=f"worker failed: {exc}")
                bar.update(1)
    return [
        _named(r, shown, used)
        for r, shown, used in zip(results, paths, absolute, strict=True)
        if r is not None
    ]


def _named(result: FileResult, shown: str, used: str) -> FileResult:
    """``result`` naming its file as the user did (the workers were given absolute paths,
    so that a cluster's workers find them)."""
    if shown == used:
        return replace(result, path=shown)
    return replace(
        result,
        path=shown,
        warnings=tuple(w.replace(used, shown) for w in result.warnings),
        error=result.error.replace(used, shown),
    )


@contextlib.contextmanager
def _local_client(distributed: Any, workers: int) -> Iterator[Any]:
    """A Client of a LocalCluster of ``workers`` single-threaded processes on loopback."""
    import dask

    # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536, which returns freed memory
    # to the system at once: the estimator's many small numpy temporaries then cost ~45 %
    # more CPU (a 10 s P-12 replay, 4.1 s instead of 2.8 s, with it set and unset in a
    # plain process here). The workers keep glibc's own adaptive threshold.
    environ = {
        k: v
        for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
        if k != MALLOC_TRIM
    }
    with (
        dask.config.set({"distributed.nanny.pre-spawn-environ": environ}),
        _quiet_dask(),
        distributed.LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
            # No dashboard; the scheduler's HTTP routes on a free loopback port, not 8787.
            dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
            # The work per file is what the single-file command needs: no second limit.
            memory_limit=0, silence_logs=logging.ERROR,
        ) as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        yield client


@contextlib.contextmanager
def _quiet_dask() -> Iterator[None]:
    """Dask's own log (scheduler and nannies starting, connections) is not the user's:
    errors only while it runs; a file's failure is reported with the file."""
    logger = logging.getLogger("distributed")
    saved = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(saved)


@contextlib.contextmanager
def _remote_client(distributed: Any, address: str, command: str) -> Iterator[Any]:
    from observer.cli import UserError
    from observer.commands.display import print_warnings

    with _quiet_dask():
        try:
            client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise UserError(f"--scheduler {address}: cannot connect: {exc}") from None
        with client:
            # Someone else's cluster: say what slows it down (see _local_client), once.
            trims = sorted({v for v in client.run(malloc_trim).values() if v is not None})
            if trims:
                print_warnings(command, [
                    f"--scheduler {address}: its workers run with {MALLOC_TRIM}={trims[0]} "
                    "(dask's default), which makes every window ~45 % dearer in CPU: start "
                    "them without it (distributed.nanny.pre-spawn-environ)"
                ])  # fmt: skip
            yield client


def malloc_trim() -> str | None:
    """This process's ``MALLOC_TRIM_THRESHOLD_`` (run on each worker of a cluster)."""
    return os.environ.get(MALLOC_TRIM)


def table_rows(results: Sequence[FileResult]) -> list[dict[str, Any]]:
    """One table: each file's rows (a bad file's one row with its error), per drive and
    motor, then file, each file's rows in their order."""
    rows: list[dict[str, Any]] = []
    for r in results:
        if r.error:
            rows.append({"file": r.path, "drive_id": None, "motor_id": None, "error": r.error})
        for row in r.rows:
            rows.append({"file": r.path, **row, "error": ""})
    rows.sort(key=lambda row: (row["drive_id"] or "", row["motor_id"] or "", row["file"]))
    return rows


def columns_of(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """:data:`ID_COLUMNS`, then every other key in the order first seen."""
    columns = dict.fromkeys(ID_COLUMNS)
    for row in rows:
        columns.update(dict.fromkeys(row))
    return list(columns)


def csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    """The table as CSV (header first; None empty; floats as Python writes them: exact)."""
    columns = columns_of(rows)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow(["" if row.get(c) is None else row[c] for c in columns])
    return out.getvalue()


def write_table(path: str | None, rows: Sequence[Mapping[str, Any]]) -> None:
    """The table to ``path`` (``.csv``, ``.parquet``; atomically) or CSV to stdout.

    Raises
    ------
    observer.cli.UserError
        If it cannot be written.
    """
    from observer.commands.outputs import write_text

    if path is None:
        sys.stdout.write(csv_text(rows))
        return
    if not path.lower().endswith(".parquet"):
        write_text(path, csv_text(rows))
        return
    import pyarrow as pa
    import pyarrow.parquet as pq

    from observer.cli import UserError
    from observer.recording import atomic_open

    columns = columns_of(rows)
    data = {c: [_parquet_value(row.get(c)) for row in rows] for c in columns}
    try:
        table = pa.table(data)
    except (pa.ArrowInvalid, pa.ArrowTypeError) as exc:
        raise UserError(f"--table {path}: cannot make a Parquet table: {exc}") from None
    try:
        with atomic_open(path, "wb") as f:
            pq.write_table(table, f)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


def _parquet_value(value: Any) -> Any:
    # A column holding whole and fractional numbers is one double column.
    if isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def report(command: str, results: Sequence[FileResult], counts: Mapping[str, int]) -> int:
    """Print each file's warnings and errors and the summary on stderr; the exit status.

    Returns
    -------
    int
        0 if every file was read, 1 if some were not (their rows say why).
    """
    from observer.commands.display import print_warnings

    for r in results:
        print_warnings(command, r.warnings)
    bad = [r for r in results if r.error]
    for r in bad:
        text = r.error if r.error.startswith(r.path) else f"{r.path}: {r.error}"
        print(f"dcobserver {command}: error: {text}", file=sys.stderr)
    summary = {
        "files": len(results),
        "read": len(results) - len(bad),
        "bad": len(bad),
        **counts,
        "bad_files": [r.path for r in bad],
    }
    print(json.dumps({"summary": summary}), file=sys.stderr)
    return 1 if bad else 0


def run_table_command(
    command: str,
    args: argparse.Namespace,
    work: FileWork,
    options: Any,
    *,
    progress: bool,
    one_file_options: Sequence[str],
    what: str,
) -> int:
    """Expand the inputs, check the output, run every file, write the table.

    Parameters
    ----------
    command : str
    args : argparse.Namespace
        With ``recording``, ``table``, ``workers``, ``scheduler``, ``config``.
    work, options
        As :func:`run_files` takes them.
    progress : bool
    one_file_options : sequence of str
        The command's options for one recording (``--json``, ``--report``): an error here.
    what : str
        What the table holds ("every window's estimate"), for that error.

    Returns
    -------
    int
        :func:`report`'s exit status.
    """
    from observer.cli import UserError

    if any(getattr(args, o.lstrip("-").replace("-", "_")) for o in one_file_options):
        listed = ", ".join(one_file_options[:-1]) + f" and {one_file_options[-1]}"
        raise UserError(f"{listed} take one recording; with many, the table (--table) holds {what}")
    paths = expand(args.recording)
    check_table_output(args.table, [*paths, *([args.config] if args.config else [])])
    results = run_files(
        command, work, paths, options,
        workers=args.workers, scheduler=args.scheduler, progress=progress,
    )  # fmt: skip
    rows = table_rows(results)
    write_table(args.table, rows)
    return report(command, results, {"rows": sum(1 for row in rows if not row["error"])})
