"""What each window pays for (swarm, polish, EIV, uncertainty: evaluations, ms), and replay speed.

Runs ``dcobserver replay``'s code path (:func:`observer.service.daemon.run_offline`)
over a simulated P-12 recording at 10 kHz with both circuits, the daemon's
default configuration, and attributes every call of the two numerical
kernels (the swarm's cost, :func:`~observer.estimation.intersample_kernels.moment_swarm_costs`,
the polish's residual, :func:`~observer.estimation.intersample_kernels.moment_residual`,
and its residual with the Jacobian,
:func:`~observer.estimation.intersample_kernels.moment_residual_jacobian`)
and the time of every stage to the stage that made it. Windows are split into
the first ones (cold swarms, chain still being decided) and the warm rest.

The instrumentation wraps the stage functions where the estimators look them
up and the three kernels where :mod:`observer.estimation.problem` calls them; it
adds about a microsecond per call. Replay speed is also measured without it,
in the same run: data seconds per wall-clock second (CPU time of the thread as
well, which other processes on a shared machine do not inflate).

Run ``python -m bench.window_work --help``.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.common import machine_description
from observer.config import Config, ObserverConfig
from observer.estimation import armature, field, stages
from observer.estimation import intersample_kernels as ik
from observer.estimation.motor import P12
from observer.recording import write_recording
from observer.service import window_observer
from observer.service.daemon import run_offline
from observer.service.window_observer import WindowResult, warm_up_kernels
from observer.simulation.converter import PRESETS
from observer.simulation.simulate import simulate
from replay.source import ReplayOptions, ReplaySource

#: Target of issue 12: offline replay at 10 kHz, both circuits.
TARGET_REPLAY_X = 30.0

Key = tuple[str, str, str]
"""(circuit, "first" or "warm", stage)."""

#: The stages as the estimators and :func:`~observer.estimation.stages.search_and_polish` call them.
STAGES = ("settled_stage", "swarm_stage", "hold_or_smooth", "polish_stage", "eiv_stage",
          "specification_stage", "std_stage")  # fmt: skip


class Ledger:
    """Evaluations and CPU time per (circuit, warm?, stage), gathered over windows."""

    def __init__(self, cold_windows: int) -> None:
        self.cold_windows = cold_windows
        self.stage: list[str] = []
        self.circuit = ""
        self.window = 0
        self.seconds: dict[Key, float] = defaultdict(float)
        self.particle_samples: dict[Key, int] = defaultdict(int)
        self.swarm_evals: dict[Key, int] = defaultdict(int)
        self.residuals: dict[Key, int] = defaultdict(int)
        self.jacobians: dict[Key, int] = defaultdict(int)
        self.windows: dict[tuple[str, str], set[int]] = defaultdict(set)

    @property
    def group(self) -> str:
        return "first" if self.window < self.cold_windows else "warm"

    def key(self, stage: str | None = None) -> Key:
        name = stage if stage is not None else (self.stage[-1] if self.stage else "other")
        return (self.circuit, self.group, name)

    @contextlib.contextmanager
    def in_stage(self, name: str) -> Iterator[None]:
        outer = self.key()
        self.stage.append(name)
        t0 = time.thread_time()
        try:
            yield
        finally:
            spent = time.thread_time() - t0
            self.stage.pop()
            self.seconds[self.key(name)] += spent
            if self.stage:  # an inner stage's time is not its caller's own
                self.seconds[outer] -= spent


def instrument(ledger: Ledger) -> Callable[[], None]:
    """Wrap the stages and kernels; returns the function that undoes it."""
    undo: list[tuple[Any, str, Any]] = []

    def patch(module: Any, name: str, wrapper: Any) -> None:
        undo.append((module, name, getattr(module, name)))
        setattr(module, name, wrapper)

    def staged_as(stage: str, original: Any) -> Any:
        def staged(*a: Any, **kw: Any) -> Any:
            with ledger.in_stage(stage):
                return original(*a, **kw)

        return staged

    # Where the estimators look the stages up, and where search_and_polish does.
    for module in (field, armature, stages):
        for stage in STAGES:
            if hasattr(module, stage):
                patch(module, stage, staged_as(stage, getattr(module, stage)))
    for circuit in ("field", "armature"):
        estimator = "estimate_field" if circuit == "field" else "estimate_armature"
        original_est = getattr(window_observer, estimator)

        def estimate(*a: Any, _o: Any = original_est, _c: str = circuit, **kw: Any) -> Any:
            ledger.circuit = _c
            ledger.windows[(_c, ledger.group)].add(ledger.window)
            with ledger.in_stage("other"):
                return _o(*a, **kw)

        patch(window_observer, estimator, estimate)

    swarm_kernel = ik.moment_swarm_costs
    residual_kernel = ik.moment_residual
    jacobian_kernel = ik.moment_residual_jacobian

    def counted_swarm(x: np.ndarray, *a: Any) -> np.ndarray:
        k = ledger.key()
        ledger.swarm_evals[k] += x.shape[0]
        ledger.particle_samples[k] += x.shape[0] * int(np.sum(a[4] - a[3] + 1))
        return swarm_kernel(x, *a)

    def counted_residual(*a: Any) -> None:
        ledger.residuals[ledger.key()] += 1
        residual_kernel(*a)

    def counted_jacobian(*a: Any) -> None:
        ledger.jacobians[ledger.key()] += 1
        jacobian_kernel(*a)

    patch(ik, "moment_swarm_costs", counted_swarm)
    patch(ik, "moment_residual", counted_residual)
    patch(ik, "moment_residual_jacobian", counted_jacobian)

    def restore() -> None:
        for module, name, original in reversed(undo):
            setattr(module, name, original)

    return restore


def replay(path: Path, config: Config, ledger: Ledger | None) -> tuple[float, float, int]:
    """Wall and CPU seconds of one offline replay, and the windows it estimated."""
    source = ReplaySource(ReplayOptions(path=str(path), speed=0.0, block_s=0.1))
    estimated = 0

    def on_result(result: WindowResult) -> None:
        nonlocal estimated
        if result.estimate is not None:
            estimated += 1
        if ledger is not None:
            ledger.window = result.index + 1

    if ledger is not None:
        ledger.window = 0
    t0, c0 = time.perf_counter(), time.thread_time()
    run_offline(config, source, on_result=on_result)
    return time.perf_counter() - t0, time.thread_time() - c0, estimated


def both_cores(rec: Any, repeats: int) -> tuple[list[float], list[float]]:
    """Wall times of one window's field and armature estimates in turn, and in two threads.

    Warm-window settings (the default warm swarm around the truth); the two
    estimates share nothing, and their numba kernels release the GIL.
    """
    from concurrent.futures import ThreadPoolExecutor

    from observer.estimation import estimate_armature, estimate_field

    cfg = ObserverConfig()
    n = int(round(cfg.window_s / rec.dt))
    s = {c: np.ascontiguousarray(rec[c][-n:], dtype=np.float64) for c in
         ("va", "ia", "vf", "if", "omega")}  # fmt: skip
    warm = dict(n_particles=cfg.warm_particles, max_iterations=cfg.warm_iterations,
                intersample="hold")  # fmt: skip

    def run_field() -> object:
        return estimate_field(s["vf"], s["if"], rec.dt, rng=0, x0=(185.0, 50.0), **warm)

    def run_armature() -> object:
        return estimate_armature(
            s["va"], s["ia"], s["if"], s["omega"], rec.dt, rng=0, x0=(3.5, 0.02), **warm
        )

    serial, threaded = [], []
    with ThreadPoolExecutor(max_workers=2) as pool:
        run_field(), run_armature()
        for _ in range(repeats):
            t0 = time.perf_counter()
            run_field()
            run_armature()
            serial.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            futures = [pool.submit(run_field), pool.submit(run_armature)]
            for f in futures:
                f.result()
            threaded.append(time.perf_counter() - t0)
    return serial, threaded


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.window_work",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--duration", type=float, default=12.0, help="recording length (s)")
    parser.add_argument("--rate", type=float, default=10_000.0, help="sample rate (Hz)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the recording")
    parser.add_argument(
        "--preset", default="ideal", choices=sorted(PRESETS),
        help="the simulated drive: ideal (held voltages) or realistic (converter-fed)",
    )  # fmt: skip
    parser.add_argument(
        "--cold-windows", type=int, default=12, help="windows counted as the start (cold, chain)"
    )
    parser.add_argument(
        "--thread-repeats", type=int, default=20, help="timed windows of the two-thread test"
    )
    parser.add_argument(
        "--decimate", type=int, default=1, help="[observer] decimate (average N samples)"
    )
    parser.add_argument("--output", type=Path, default=Path("docs/window_work.md"))
    parser.add_argument("--quick", action="store_true", help="smoke run: 3 s at 2 kHz")
    args = parser.parse_args(argv)
    if args.quick:
        args.duration, args.rate, args.cold_windows, args.thread_repeats = 3.0, 2000.0, 5, 2
    if args.duration < 2.0 or args.rate < 100:
        parser.error("--duration must be >= 2 s and --rate >= 100 Hz")
    if args.decimate < 1:
        parser.error("--decimate must be >= 1")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_description()
    warm_up_kernels()
    config = Config(observer=ObserverConfig(decimate=args.decimate))
    with tempfile.TemporaryDirectory(prefix="dcobserver-work-") as tmp:
        path = Path(tmp) / "p12.mcap"
        rec = simulate(
            P12, duration_s=args.duration, sample_rate_hz=args.rate, seed=args.seed,
            drive=PRESETS[args.preset], drive_name=args.preset,
        )  # fmt: skip
        write_recording(rec, path)
        data_s = float(rec.t[-1] - rec.t[0])
        wall, cpu, n_est = replay(path, config, None)  # plain, as `dcobserver replay`
        serial, threaded = both_cores(rec, args.thread_repeats)
        ledger = Ledger(args.cold_windows)
        restore = instrument(ledger)
        try:
            replay(path, config, ledger)
        finally:
            restore()
    hop = config.observer.hop_s
    lines = [
        "# Work per window: what the observer's estimate of each window pays for",
        "",
        f"Made by `python -m bench.window_work{' ' + ' '.join(argv) if argv else ''}` on "
        f"{machine}. A simulated P-12 ({args.preset} drive), {args.duration:g} s at "
        f"{args.rate:g} Hz, both circuits, "
        f"default `[observer]` (window {config.observer.window_s:g} s, hop {hop:g} s, "
        f"decimate {config.observer.decimate}, cold "
        f"{config.observer.cold_particles}×{config.observer.cold_iterations}, warm "
        f"{config.observer.warm_particles}×{config.observer.warm_iterations}), through "
        "`dcobserver replay`'s code path. Times are the thread's CPU time.",
        "",
        f"**Replay speed** (uninstrumented run): {n_est} windows in {wall:.2f} s wall / "
        f"{cpu:.2f} s CPU for {data_s:.1f} s of data: **{data_s / wall:.2f}× real time** by wall "
        f"clock, {data_s / cpu:.2f}× by CPU time; {1e3 * cpu / max(n_est, 1):.1f} ms CPU per "
        f"window (real time needs < {1e3 * hop:g} ms; {TARGET_REPLAY_X:g}× needs "
        f"< {1e3 * hop / TARGET_REPLAY_X:.1f} ms).",
        "",
        "| circuit | windows | stage | ms / window | share | swarm evaluations / window | "
        "particle-samples / window | residual evaluations / window | "
        "residual + Jacobian evaluations / window |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    short = [lines[6]]
    stages = STAGES + ("other",)
    for circuit in ("field", "armature"):
        for group in ("first", "warm"):
            n = len(ledger.windows[(circuit, group)])
            if not n:
                continue
            keys = [(circuit, group, st) for st in stages]
            total = sum(ledger.seconds[k] for k in keys)
            lines.append(
                f"| {circuit} | {group} {n} | **all** | **{1e3 * total / n:.1f}** | 100 % | "
                f"{sum(ledger.swarm_evals[k] for k in keys) / n:.0f} | "
                f"{sum(ledger.particle_samples[k] for k in keys) / n:.3g} | "
                f"{sum(ledger.residuals[k] for k in keys) / n:.0f} | "
                f"{sum(ledger.jacobians[k] for k in keys) / n:.0f} |"
            )
            short.append(f"{circuit} {group} ({n} windows): {1e3 * total / n:.1f} ms/window")
            for k in keys:
                if k not in ledger.seconds:
                    continue
                ms = 1e3 * ledger.seconds[k] / n
                lines.append(
                    f"| {circuit} | {group} {n} | {k[2]} | {ms:.2f} | "
                    f"{100 * ledger.seconds[k] / max(total, 1e-12):.0f} % | "
                    f"{ledger.swarm_evals[k] / n:.0f} | {ledger.particle_samples[k] / n:.3g} | "
                    f"{ledger.residuals[k] / n:.0f} | {ledger.jacobians[k] / n:.0f} |"
                )
                short.append(
                    f"  {k[2]:<20} {ms:7.2f} ms  swarm evals {ledger.swarm_evals[k] / n:6.0f}"
                    f"  residuals {ledger.residuals[k] / n:5.0f}"
                    f"  r+J {ledger.jacobians[k] / n:5.0f}"
                )
    lines += [
        "",
        "`other` is the estimator's own work outside the stages (search range, choice of the "
        "intersample model, the window's problem with its cubic moments); `hold_or_smooth` "
        "holds the two polishes of a window whose model is still being decided; "
        "`settled_stage` a settled window's start from the tracked state (one cost "
        "evaluation; its polish is counted under `polish_stage`), which runs no swarm unless "
        "that polish fails. Residual "
        "evaluations are the specification test's Levenberg-Marquardt steps, and the "
        "finite-difference columns of a fitted shift or lag; residual + Jacobian evaluations "
        "the polish's steps, each with the exact sensitivities to ln R, ln L and K "
        "(`moment_residual_jacobian`).",
        "",
    ]
    ser, thr = float(np.median(serial)), float(np.median(threaded))
    lines += [
        "## Both cores: field and armature of one window in two threads",
        "",
        f"One warm window ({ObserverConfig().warm_particles}×{ObserverConfig().warm_iterations} "
        f"swarms, {args.rate:g} Hz), {len(serial)} rounds, wall clock, median: field then "
        f"armature in this thread {1e3 * ser:.1f} ms, both at once in two threads "
        f"{1e3 * thr:.1f} ms: **{ser / thr:.2f}×** (2× is the most two cores can give; the "
        "Python between the kernels holds the GIL, and the machine is shared).",
        "",
    ]
    short.append(f"two threads: serial {1e3 * ser:.1f} ms, threaded {1e3 * thr:.1f} ms, "
                 f"{ser / thr:.2f}x")  # fmt: skip
    text = "\n".join(lines) + "\n"
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text, encoding="utf-8")
    print("\n".join(short))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
