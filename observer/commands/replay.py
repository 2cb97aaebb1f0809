"""``dcobserver replay``: run the observer over a recording or daemon log, as fast as possible.

The first seconds of the file are checked against what a DC motor can be
before the run (:mod:`observer.estimation.plausibility`); ``--report`` and
``--png`` write the trend report (:mod:`observer.commands.trend`).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: Samples read from the start of the file for the checks before the run.
CHECK_SAMPLES = 20_000


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording", metavar="FILE", nargs="+",
        help=".mcap (a recording or daemon log) or .csv; several, a folder or a glob: one "
        "table of every window's estimate (see below)",
    )  # fmt: skip
    parser.add_argument(
        "--config", metavar="TOML", default=None,
        help="take [observer] (windows, seed, swarm, quality) from this file "
        "(default: built-in defaults)",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print each estimate as a JSON line")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--report", metavar="OUT.html", default=None,
        help="write the trend report: each parameter over time with its one-sigma band and "
        "quality, held and skipped windows marked, currents and speed below",
    )  # fmt: skip
    parser.add_argument(
        "--png", metavar="OUT.png", default=None, help="write the trend report's figure as PNG"
    )
    from observer.commands.archive import add_options

    add_options(
        parser,
        "every window's estimate (the columns: each key of --json's estimates, nested keys "
        "dotted, as field.R or armature.std.K; not elapsed_ms, the time the window took)",
    )


def _prefix(path: str) -> tuple[np.ndarray, dict[str, np.ndarray], Mapping[str, Any]]:
    """The first :data:`CHECK_SAMPLES` samples of the file: t (s), channels (SI), and the
    recording's metadata."""
    from observer.cli import UserError
    from observer.commands.archive import mcap_metadata
    from observer.recording import RecordingError, read_recording

    if not path.lower().endswith(".mcap"):
        rec = read_recording(path)
        n = min(rec.n_samples, CHECK_SAMPLES)
        return rec.t[:n], {c: np.asarray(v[:n]) for c, v in rec.signals.items()}, rec.metadata
    from replay.source import iter_mcap_blocks

    times: list[np.ndarray] = []
    parts: dict[str, list[np.ndarray]] = {}
    count = 0
    blocks = iter_mcap_blocks(path)
    # The replay itself reports a cut or a bad message; a second time here is noise.
    quiet = logging.getLogger("replay.source")
    was_disabled, quiet.disabled = quiet.disabled, True
    try:
        for block in blocks:
            times.append(np.asarray(block.t_ns))
            for c, v in block.signals.items():
                parts.setdefault(c, []).append(np.asarray(v))
            count += len(block.t_ns)
            if count >= CHECK_SAMPLES:
                break
    finally:
        quiet.disabled = was_disabled
        close = getattr(blocks, "close", None)
        if close is not None:
            close()
    if count == 0:
        try:
            read_recording(path)  # says why: not MCAP, cut before the first block, no topic
        except RecordingError as exc:
            raise UserError(str(exc)) from None
        raise UserError(f"{path}: no sample block can be read (damaged before the first one)")
    t = np.concatenate(times) / 1e9
    signals = {c: np.concatenate(v) for c, v in parts.items() if len(v) == len(times)}
    return t, signals, mcap_metadata(path)


def _check(path: str, config: Any, *, defer: bool = False) -> tuple[list[str], Mapping[str, Any]]:
    """Warnings about the file's first seconds (printed unless ``defer``) and the file's
    metadata; a one-line error if it cannot be a motor's."""
    from observer.commands.display import report_findings
    from observer.estimation import CIRCUIT_CHANNELS, check_data

    t, signals, metadata = _prefix(path)
    finite = np.isfinite(t)
    steps = np.diff(t[finite])
    steps = steps[steps > 0]
    if steps.size == 0:
        return [], metadata
    wanted = config.observer.circuits
    circuits = [
        c
        for c in ("field", "armature")
        if wanted in ("both", c) and all(ch in signals for ch in CIRCUIT_CHANNELS[c])
    ]
    clean = {c: np.nan_to_num(v[finite], nan=0.0) for c, v in signals.items()}
    findings = check_data(clean, float(np.median(steps)), circuits, t=t[finite])
    # A log may hold gaps and stuck stretches: the observer skips those windows itself.
    findings = [f for f in findings if f.code not in ("stuck", "too_short")]
    warnings = report_findings("replay", findings, path=path, units_option=False, defer=defer)
    return warnings, metadata


def _source(path: str) -> Any:
    """The replay source of ``path``, as fast as it reads (one code path for one file and
    for many)."""
    from replay.source import ReplayOptions, ReplaySource

    return ReplaySource(ReplayOptions(path=path, speed=0.0, block_s=0.1))


def _nothing_estimated(path: str, config: Any) -> str:
    return (
        f"{path}: no window was estimated: a window is observer.window_s = "
        f"{config.observer.window_s:g} s of samples (a shorter recording has none), and "
        "windows with gaps or stuck sensors are skipped"
    )


def window_rows(path: str, config: Any) -> tuple[list[dict[str, Any]], list[str]]:
    """Every estimated window of one recording as a table row, and its warnings.

    The work of ``dcobserver replay FILE`` (same checks, source, observer and ids),
    for :func:`observer.commands.archive.run_files`: a row is the window's
    ``--json`` line flattened (:func:`~observer.commands.archive.flatten`) without
    ``elapsed_ms`` and ``units``.

    Raises
    ------
    observer.cli.UserError
        (and the readers' errors) for a file that is not a usable recording.
    """
    from observer.commands.archive import flatten, recording_ids
    from observer.service.daemon import run_offline

    warnings, metadata = _check(path, config, defer=True)
    ids = recording_ids(path, config, metadata)
    rows: list[dict[str, Any]] = []

    def on_result(result: Any) -> None:
        if result.estimate is not None:
            estimate = {**ids, **result.estimate}
            estimate.pop("elapsed_ms", None)
            rows.append(flatten(estimate))

    observer = run_offline(config, _source(path), on_result=on_result)
    if not observer.health()["windows"].get("estimated"):
        warnings.append(_nothing_estimated(path, config))
    return rows, warnings


class _Tap:
    """Passes a source's blocks through, showing each to ``on_block`` (for the trend)."""

    def __init__(self, source: Any, on_block: Any) -> None:
        self.source = source
        self.on_block = on_block

    def __enter__(self) -> _Tap:
        self.source.__enter__()
        return self

    def __exit__(self, *exc: Any) -> Any:
        return self.source.__exit__(*exc)

    def __iter__(self) -> Any:
        for block in self.source:
            self.on_block(block)
            yield block


def main(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from observer.commands.archive import recording_ids, run_table_command, wants_table
    from observer.commands.display import ESTIMATE_UNITS, print_warnings
    from observer.commands.outputs import check_input, check_outputs, write_bytes, write_text
    from observer.commands.run import format_estimate
    from observer.commands.trend import Trend, render_html, render_png
    from observer.config import Config, load_config
    from observer.service.circuit_worker import parallel_wanted
    from observer.service.daemon import run_offline
    from observer.service.mcaplog import to_json
    from observer.service.window_observer import WindowResult
    from observer.service.zenohconf import names

    config = load_config(args.config) if args.config else Config()
    if wants_table(args):
        return run_table_command(
            "replay", args, window_rows, config, progress=not args.no_progress,
            one_file_options=("--json", "--report", "--png"), what="every window's estimate",
        )  # fmt: skip
    path = args.recording[0]
    check_input(path)
    check_outputs(("--report", args.report), ("--png", args.png), inputs=[path])
    _, metadata = _check(path, config)
    source: Any = _source(path)
    trend = Trend()
    if args.report or args.png:
        source = _Tap(source, lambda block: trend.add_block(block.t_ns, block.signals))
    bar = tqdm(
        unit="sample", unit_scale=True, disable=args.no_progress, file=sys.stderr,
        desc=Path(path).name,
    )  # fmt: skip
    ids = names(**recording_ids(path, config, metadata))
    units = ESTIMATE_UNITS

    def on_result(result: WindowResult) -> None:
        trend.add_window(result.t1_ns, result.estimate, result.skip_reason)
        if result.estimate is None:
            return
        estimate = {**ids, **result.estimate}
        if args.json:
            sys.stdout.write(to_json({**estimate, "units": units}).decode() + "\n")
        else:
            bar.write(format_estimate(estimate))

    try:
        observer = run_offline(
            config, source, on_result=on_result, progress=bar.update,
            parallel=parallel_wanted(config.observer.parallel_circuits),
        )  # fmt: skip
    finally:
        bar.close()
    summary = observer.health()
    print(json.dumps({"summary": summary["windows"]}), file=sys.stderr)
    if not summary["windows"].get("estimated"):
        # Exit 0 and an empty summary read as "fine": say that there is no answer, and why.
        print_warnings("replay", [_nothing_estimated(path, config)])
    title = f"dcobserver trend of {Path(path).name}"
    if args.report:
        write_text(args.report, render_html(trend, title=title, source=path))
    if args.png:
        write_bytes(args.png, render_png(trend, title=title))
    return 0
