"""Benchmark of the daemon at 10 kHz x 6 channels (t + 5 signals), 1 s window, 100 ms hop.

Measures, on a simulated P-12 recording replayed through the real pipeline
(replay source -> ring buffer -> observer -> Zenoh publisher + MCAP log):

1. real-time replay: ring-buffer overruns, windows skipped for lateness,
   estimate latency (the window's last sample written to the ring -> estimate
   published on Zenoh) p50 / p99;
2. offline replay (``dcobserver replay``'s code path) as fast as possible:
   speed relative to real time.

Usage::

    python bench/daemon_bench.py [--duration S] [--decimate K ...] [--rate HZ] [--preset P]

``--preset ideal`` (the default) simulates voltages held over each sample, the
drive's own references; ``--preset realistic`` the converter-fed drive a shovel
has (thyristor bridges, filters, 12-bit ADC, ``simulate --preset realistic``),
whose windows take the intersample model and cost more.

The issue asks for a 10-minute real-time replay (``--duration 600``); the
default 60 s is said so in the output. The real-time replay runs over a
recording as long as itself, not a loop: where a looped recording jumps from
its end back to its start (speed, currents and their history at once, as no
motor does) the windows across the seam are hard ones, cold-like fits of a
discontinuity, ~7 of every loop; over a 30 s loop they were 2 % of the windows
and set the p99 latency (``--loop S`` measures that case). The offline replay
runs over the first ``--offline-duration`` seconds.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from observer.service.threads import one_blas_thread  # noqa: E402

one_blas_thread()  # as the dcobserver command does, before numpy loads its BLAS

from observer.config import Config, LogConfig, ObserverConfig, ZenohConfig  # noqa: E402
from observer.estimation.motor import P12  # noqa: E402
from observer.recording import write_recording  # noqa: E402
from observer.service.circuit_worker import parallel_wanted  # noqa: E402
from observer.service.daemon import Daemon, run_offline  # noqa: E402
from observer.service.window_observer import warm_up_kernels  # noqa: E402
from observer.simulation.converter import PRESETS  # noqa: E402
from observer.simulation.simulate import simulate  # noqa: E402
from replay.source import ReplayOptions, ReplaySource  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="real-time replay (s)")
    parser.add_argument("--rate", type=float, default=10_000.0, help="sample rate (Hz)")
    parser.add_argument("--decimate", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--offline-duration", type=float, default=60.0)
    parser.add_argument(
        "--preset", default="ideal", choices=sorted(PRESETS),
        help="the simulated drive (default ideal: held voltages)",
    )  # fmt: skip
    parser.add_argument("--no-log", action="store_true", help="run without the MCAP log")
    parser.add_argument(
        "--loop", type=float, default=0.0, metavar="S",
        help="loop the real-time replay over a recording of S seconds (default: one as long "
        "as the run, no seam)",
    )  # fmt: skip
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")

    tmp = Path(tempfile.mkdtemp(prefix="dcobserver-bench-"))
    # The real-time replay runs over a recording a little longer than itself (the
    # daemon's first window waits for a full window), unless told to loop.
    length = args.offline_duration
    live_length = args.loop if args.loop > 0 else args.duration + 5.0

    def recording(seconds: float, name: str) -> Path:
        print(f"simulating {seconds:g} s of the P-12 at {args.rate:g} Hz, drive "
              f"{args.preset} ...", flush=True)  # fmt: skip
        rec = simulate(
            P12, duration_s=seconds, sample_rate_hz=args.rate, noise=0.002, seed=1,
            drive=PRESETS[args.preset], drive_name=args.preset,
        )  # fmt: skip
        out = tmp / name
        write_recording(rec, out)
        print(f"recording: {out} ({out.stat().st_size / 1e6:.1f} MB)")
        return out

    path = recording(length, "bench.mcap")
    live_path = path if live_length == length else recording(live_length, "live.mcap")
    print(f"numba warm-up: {warm_up_kernels():.1f} s")
    if args.duration < 600:
        print(f"NOTE: real-time replay shortened to {args.duration:g} s (issue: 10 min)")

    for k in args.decimate:
        obs = ObserverConfig(drive_id="bench", window_s=1.0, hop_s=0.1, decimate=k)
        config = Config(
            observer=obs,
            zenoh=ZenohConfig(listen=[f"tcp/127.0.0.1:{_free_port()}"]),
            log=LogConfig(dir="" if args.no_log else str(tmp / f"log-d{k}")),
        )
        source = ReplaySource(
            ReplayOptions(path=str(live_path), speed=1.0, block_s=0.01, loop=args.loop > 0)
        )
        elapsed: list[float] = []
        daemon = Daemon(
            config, source, sample_rate_hint_hz=args.rate,
            on_estimate=lambda e, store=elapsed: store.append(e["elapsed_ms"]),
        )  # fmt: skip
        daemon.start()
        started = time.monotonic()
        while time.monotonic() - started < args.duration and not daemon.finished.is_set():
            time.sleep(0.5)
        health = daemon.health()
        daemon.stop()
        lat = sorted(daemon.latencies_ms)
        q = statistics.quantiles(lat, n=100)
        windows = health["observer"]["windows"]
        print(
            f"real time, decimate={k}: {args.duration:g} s, {windows.get('estimated', 0)} "
            f"estimates, ring overruns {health['ring']['overruns']} "
            f"({health['ring']['overrun_samples']} samples), late windows "
            f"{windows.get('late', 0)}, latency p50 {q[49]:.1f} ms p99 {q[98]:.1f} ms "
            f"max {lat[-1]:.1f} ms (estimation alone p50 {statistics.median(elapsed):.1f} ms "
            f"p99 {statistics.quantiles(elapsed, n=100)[98]:.1f} ms), "
            f"zenoh published {health['zenoh']['published']}, "
            f"armature in a second process: {health['observer']['parallel']['state']} "
            f"({health['observer']['parallel']['windows']} windows), "
            f"{'looped over ' + format(args.loop, 'g') + ' s, ' if args.loop > 0 else ''}"
            f"log {health['log'].get('bytes', 0) / 1e6:.1f} MB"
        )

        offline = ReplaySource(ReplayOptions(path=str(path), speed=0.0, block_s=0.1))
        t0 = time.monotonic()
        # As `dcobserver replay` runs it: the armature in a second process where wanted.
        observer = run_offline(
            Config(observer=obs), offline, sample_rate_hint_hz=args.rate,
            parallel=parallel_wanted(obs.parallel_circuits),
        )  # fmt: skip
        wall = time.monotonic() - t0
        n = observer.counts.get("estimated", 0)
        print(
            f"offline, decimate={k}: {length:g} s of data in {wall:.1f} s = "
            f"{length / wall:.1f}x real time ({n} estimates)"
        )
    os.system(f"rm -rf {tmp}")  # noqa: S605 - our own temporary folder
    return 0


if __name__ == "__main__":
    sys.exit(main())
