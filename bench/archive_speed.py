"""A fleet archive replayed serially and on a local Dask cluster: wall clock and ratio.

Makes ``--files`` simulated P-12 recordings (``--duration`` s at ``--rate`` Hz, the ideal
drive, seeds 1..N) in a temporary folder, then runs ``dcobserver replay FOLDER --table
...`` as a user would, each run its own process: ``--workers 1`` (one after the other in
that process) and ``--workers 2`` (a ``distributed.LocalCluster`` of two single-threaded
worker processes, the default on a 2-core machine), round-robin ``--repeats`` times, and
checks that every run's table is the same, byte for byte. The wall clock includes what a
user waits for: the process start, the cluster's start and stop, the numba kernels loaded
from their cache in each process. The CPU time is the run's and its children's
(``RUSAGE_CHILDREN``).

Run ``python -m bench.archive_speed --help``; writes docs/archive_speed.md unless ``--out -``.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from bench.common import machine_description

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = REPO / "docs" / "archive_speed.md"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.archive_speed", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--files", type=int, default=8, help="recordings (default: 8)")
    parser.add_argument("--duration", type=float, default=10.0, help="s each (default: 10)")
    parser.add_argument("--rate", type=float, default=2000.0, help="Hz (default: 2000)")
    parser.add_argument("--repeats", type=int, default=1, help="rounds of both (default: 1)")
    parser.add_argument(
        "--out", default=str(DEFAULT_OUT), help=f"report file, - for none (default: {DEFAULT_OUT})"
    )
    parser.add_argument("--start-only", choices=STARTS, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


#: The two ways of running tasks in local processes that dask offers.
STARTS = ("LocalCluster", "processes")


def load_kernels(i: int) -> int:
    """A task that loads what a file's replay needs (modules, numba kernels from cache)."""
    import observer.commands.replay  # noqa: F401
    import observer.estimation.intersample_kernels  # noqa: F401

    return i


def start_only(kind: str) -> None:
    """Two local workers, four tasks that only load the kernels, then stop (a child)."""
    import logging

    if kind == "LocalCluster":
        import distributed

        with (
            distributed.LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.ERROR,
            ) as cluster,
            distributed.Client(cluster) as client,
        ):  # fmt: skip
            client.gather([client.submit(load_kernels, i, pure=False) for i in range(4)])
    else:
        import dask

        tasks = [dask.delayed(load_kernels)(i) for i in range(4)]
        dask.compute(*tasks, scheduler="processes", num_workers=2)


def startup(kind: str) -> float:
    """Wall seconds of :func:`start_only` in a new process (imports included)."""
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "bench.archive_speed", "--start-only", kind],
        check=True, capture_output=True, cwd=REPO,
    )  # fmt: skip
    return time.perf_counter() - start


def make_archive(folder: Path, files: int, duration_s: float, rate_hz: float) -> float:
    """Write the recordings; returns their total data seconds."""
    from observer.estimation.motor import P12
    from observer.recording import write_recording
    from observer.simulation.simulate import simulate

    total = 0.0
    for seed in range(1, files + 1):
        rec = simulate(P12, duration_s=duration_s, sample_rate_hz=rate_hz, seed=seed)
        write_recording(rec, folder / f"p12-{seed:03d}.mcap")
        total += float(rec.t[-1] - rec.t[0])
    return total


def run(folder: Path, table: Path, workers: int) -> tuple[float, float]:
    """``dcobserver replay FOLDER --workers N``: wall and CPU seconds (with children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "observer.cli", "replay", str(folder), "--table", str(table),
         "--workers", str(workers), "--no-progress"],
        capture_output=True, text=True, cwd=REPO,
    )  # fmt: skip
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise SystemExit(f"replay --workers {workers} failed ({done.returncode}):\n{done.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main(argv: Sequence[str] | None = None) -> int:
    shown = list(argv) if argv is not None else sys.argv[1:]
    args = parse_args(argv)
    if args.start_only:
        start_only(args.start_only)
        return 0
    machine = machine_description()
    starts: dict[str, list[float]] = {k: [] for k in STARTS}
    for _ in range(2):
        for kind in STARTS:
            starts[kind].append(startup(kind))
    times: dict[int, list[tuple[float, float]]] = {1: [], 2: []}
    with tempfile.TemporaryDirectory(prefix="dcobserver-archive-") as tmp:
        folder = Path(tmp) / "archive"
        folder.mkdir()
        data_s = make_archive(folder, args.files, args.duration, args.rate)
        tables: set[str] = set()
        for r in range(args.repeats):
            for workers in (1, 2):
                table = Path(tmp) / f"table-{workers}-{r}.csv"
                times[workers].append(run(folder, table, workers))
                tables.add(table.read_text())
                print(f"workers {workers}: {times[workers][-1][0]:.1f} s wall", file=sys.stderr)
        rows = next(iter(tables)).count("\n") - 1
    same = len(tables) == 1
    best = {w: min(t[0] for t in ts) for w, ts in times.items()}
    cpu = {w: min(t[1] for t in ts) for w, ts in times.items()}
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    lines = [
        "# A fleet archive: serial against a local Dask cluster",
        "",
        f"Made by `python -m bench.archive_speed{' ' + ' '.join(shown) if shown else ''}` on "
        f"{machine}; load average at the end {load}. {args.files} simulated P-12 recordings "
        f"of {args.duration:g} s at {args.rate:g} Hz ({data_s:.0f} s of data, {rows} windows "
        "estimated), `dcobserver replay FOLDER --table T.csv`, each run its own process; "
        f"best of {args.repeats}.",
        "",
        "| run | wall (s) | CPU incl. workers (s) | data s per wall s |",
        "|---|---|---|---|",
        f"| `--workers 1` (serial, in the process) | {best[1]:.1f} | {cpu[1]:.1f} | "
        f"{data_s / best[1]:.1f} |",
        f"| `--workers 2` (LocalCluster, 2 processes) | {best[2]:.1f} | {cpu[2]:.1f} | "
        f"{data_s / best[2]:.1f} |",
        "",
        f"Speed-up of two workers: **{best[1] / best[2]:.2f}×**. Tables identical in every "
        f"run: {'yes' if same else 'NO'}.",
        "",
        "The fixed cost of two local workers: a new process starts them, runs four tasks that "
        "only load the replay's modules and kernels, and stops them (best of 2): "
        f"`distributed.LocalCluster` {min(starts['LocalCluster']):.1f} s, dask's `processes` "
        f"scheduler {min(starts['processes']):.1f} s.",
        "",
    ]
    text = "\n".join(lines)
    print(text)
    if args.out != "-":
        Path(args.out).write_text(text)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
