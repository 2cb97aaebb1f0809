"""Benchmark this project's PSO estimator against its peers, on one machine, in one run.

Same data (a window of a simulated P-12 recording with a field step), same
cost budget (particles x iterations), same machine, one process:

1. **speed** of one field estimate: this PSO (``estimate_field`` with polish
   off, and the bare ``observer.estimation.pso.minimize`` on ``kernels.rl_swarm_costs``)
   against pyswarms ``GlobalBestPSO`` with a numpy objective and with this
   project's compiled cost, scipy's ``differential_evolution`` and
   ``least_squares``, and equation-error least squares / recursive least squares;
2. **bias against noise**: the classical equation-error methods against this
   output-error estimator as the sensor noise grows;
3. **Monte Carlo** over many seeds: each estimator's RMSE against the
   Cramer-Rao bound, with noise on the measured currents only (output error is
   then maximum likelihood) and with noise on every channel (errors in variables).

Prints a table of time ratios and writes the whole report as markdown
(``docs/benchmarks.md``). Run ``python -m bench.bench_pso --help``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from bench import peers
from bench.common import (
    SAMPLE_RATE_HZ,
    WINDOW_SAMPLES,
    Window,
    machine_description,
    p12_window,
)
from observer.estimation import (
    CircuitEstimate,
    estimate_armature,
    estimate_field,
    field_search_range,
    kernels,
    pso,
)
from observer.estimation.motor import P12
from observer.simulation.simulate import NoiseLevels

#: Targets from issue 2.
TARGET_MEDIAN_MS = 10.0
TARGET_VS_PYSWARMS_NUMPY = 50.0
TARGET_VS_PYSWARMS_COMPILED = 3.0
TARGET_TOLERANCE = {"Rf": 0.01, "Lf": 0.01, "Ra": 0.01, "K": 0.01, "La": 0.05}
TARGET_RMSE_CRLB = 1.5
#: Recording seeds: timing window ``--seed``; bias table, Monte Carlo and window study from:
BIAS_FIRST_SEED = 1000
MC_FIRST_SEED = 2000
#: Back-to-back kernel calls per timed run of the kernel alone.
KERNEL_BATCH = 20
WINDOW_FIRST_SEED = 3000


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.bench_pso",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--particles", type=int, default=100, help="swarm size of the budget")
    parser.add_argument("--iterations", type=int, default=100, help="iterations of the budget")
    parser.add_argument("--repeats", type=int, default=30, help="timed runs per fast method")
    parser.add_argument(
        "--slow-repeats", type=int, default=3, help="timed runs of pyswarms with numpy objectives"
    )
    parser.add_argument("--mc-seeds", type=int, default=60, help="Monte Carlo seeds per case")
    parser.add_argument("--bias-seeds", type=int, default=10, help="seeds per noise level")
    parser.add_argument(
        "--noise-levels",
        type=str,
        default="0,0.001,0.002,0.005,0.01,0.02",
        help="noise levels of the bias table (fractions of rated, all channels)",
    )
    parser.add_argument(
        "--noise", type=float, default=0.002, help="realistic noise (fraction of rated)"
    )
    parser.add_argument(
        "--window-lengths",
        type=str,
        default="1000,2000,4000,8000",
        help="window lengths (samples) of the accuracy-against-window study",
    )
    parser.add_argument("--window-seeds", type=int, default=20, help="seeds per window length")
    parser.add_argument("--seed", type=int, default=0, help="seed of the timing window")
    parser.add_argument("--output", type=Path, default=Path("docs/benchmarks.md"))
    parser.add_argument(
        "--skip-pyswarms", action="store_true", help="leave pyswarms out even if installed"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 20 iterations, 2 seeds, 3 timed runs, two noise levels",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    try:
        args.levels = [float(x) for x in args.noise_levels.split(",") if x.strip()]
    except ValueError:
        parser.error(f"--noise-levels must be comma-separated numbers, got {args.noise_levels!r}")
    try:
        args.window_lengths = [int(x) for x in args.window_lengths.split(",") if x.strip()]
    except ValueError:
        parser.error(
            f"--window-lengths must be comma-separated integers, got {args.window_lengths!r}"
        )
    if not args.window_lengths or min(args.window_lengths) < 100:
        parser.error("--window-lengths needs at least one length, all >= 100 samples")
    if args.quick:
        args.iterations = min(args.iterations, 20)
        args.repeats = min(args.repeats, 3)
        args.slow_repeats = 1
        args.mc_seeds = min(args.mc_seeds, 2)
        args.bias_seeds = min(args.bias_seeds, 1)
        args.levels = args.levels[:1] + [args.noise]
        args.window_seeds = 1
        args.window_lengths = args.window_lengths[:1]
    names = ("particles", "iterations", "repeats", "slow_repeats", "mc_seeds", "bias_seeds",
             "window_seeds")  # fmt: skip
    for name in names:
        if getattr(args, name) < (2 if name == "particles" else 1):
            parser.error(f"--{name.replace('_', '-')} is too small")
    if not args.levels or any(x < 0 for x in args.levels):
        parser.error("--noise-levels needs at least one level, all >= 0")
    args.pyswarms = not args.skip_pyswarms and peers.pyswarms_available()
    return args


# ----------------------------------------------------------------- timing


@dataclass(frozen=True)
class Timed:
    """Wall times (s) of repeated runs of one method and its last estimate."""

    name: str
    times: np.ndarray
    resistance_ohm: float
    inductance_h: float
    evaluations: str
    cpu_times: np.ndarray

    @property
    def cpu_p50_ms(self) -> float:
        """Median CPU time of the thread (ms): what the run costs on one core, whatever the load."""
        return 1e3 * float(np.percentile(self.cpu_times, 50))

    @property
    def p50_ms(self) -> float:
        return 1e3 * float(np.percentile(self.times, 50))

    @property
    def p90_ms(self) -> float:
        return 1e3 * float(np.percentile(self.times, 90))

    @property
    def min_ms(self) -> float:
        return 1e3 * float(np.min(self.times))


@dataclass
class _Method:
    name: str
    run: Callable[[int], tuple[float, float]]
    runs: int
    evaluations: Callable[[], str]
    per_run: int = 1  # calls per run: times are divided by it
    times: list[float] = field(default_factory=list)
    cpu_times: list[float] = field(default_factory=list)
    last: tuple[float, float] = (math.nan, math.nan)


def _time_interleaved(methods: list[_Method], bar: tqdm) -> list[Timed]:
    """Warm every method up once, then time them round-robin.

    Interleaving spreads any change of the machine's load (it is shared) over
    all methods alike, so the ratios hold even when absolute times drift.
    """
    for m in methods:
        m.run(10_000)  # compilation, caches, imports
        bar.update(1)
    for i in range(max(m.runs for m in methods)):
        for m in methods:
            if i < m.runs:
                c0 = time.thread_time()
                t0 = time.perf_counter()
                m.last = m.run(i)
                m.times.append((time.perf_counter() - t0) / m.per_run)
                m.cpu_times.append((time.thread_time() - c0) / m.per_run)
    return [
        Timed(m.name, np.array(m.times), *m.last, m.evaluations(), np.array(m.cpu_times))
        for m in methods
    ]


def _on_window(
    fn: Callable[[np.ndarray, np.ndarray, float], tuple[float, float]],
    vf: np.ndarray,
    i_f: np.ndarray,
    dt: float,
) -> Callable[[int], tuple[float, float]]:
    def run(_seed: int) -> tuple[float, float]:
        return fn(vf, i_f, dt)

    return run


def timing(w: Window, args: argparse.Namespace, bar: tqdm) -> list[Timed]:
    """Time every method on the field window ``w`` at the same budget."""
    vf, i_f, dt = w.vf, w.i_f, w.dt
    particles, its = args.particles, args.iterations
    budget = f"{particles * (its + 1)}"
    log_bounds = field_search_range(vf, i_f, dt).log_bounds()

    def cost(x: np.ndarray) -> np.ndarray:
        return kernels.rl_swarm_costs(x, vf, i_f, dt, True)

    methods: list[_Method] = []

    def add(
        name: str, run: Callable[[int], Any], runs: int, evaluations: Any, per_run: int = 1
    ) -> None:
        count = evaluations if callable(evaluations) else (lambda: str(evaluations))
        methods.append(_Method(name, run, runs, count, per_run=per_run))

    x = np.random.default_rng(0).uniform(log_bounds[:, 0], log_bounds[:, 1], (particles, 2))

    def kernel_calls(_seed: int) -> tuple[float, float]:
        for _ in range(KERNEL_BATCH):
            cost(x)
        return math.nan, math.nan

    # Timed in batches of back-to-back calls, as the swarm makes them (a single
    # call after another method would start with its data cold in the cache),
    # and round-robin with the rest so it sees the same load.
    add(f"cost kernel alone: one `rl_swarm_costs` call ({particles} particles; runs are "
        f"batches of {KERNEL_BATCH})", kernel_calls,
        args.repeats, particles, per_run=KERNEL_BATCH)  # fmt: skip

    def ours_estimate(seed: int) -> tuple[float, float]:
        e = estimate_field(
            vf, i_f, dt, n_particles=particles, max_iterations=its, rng=seed, polish=False
        )
        return e.resistance_ohm, e.inductance_h

    def ours_minimize(seed: int) -> tuple[float, float]:
        res = pso.minimize(cost, log_bounds, n_particles=particles, max_iterations=its, rng=seed)
        return float(10.0 ** res.x[0]), float(10.0 ** res.x[1])

    def ours_full(seed: int) -> tuple[float, float]:
        e = estimate_field(vf, i_f, dt, n_particles=particles, max_iterations=its, rng=seed)
        return e.resistance_ohm, e.inductance_h

    add("**this PSO: `estimate_field(polish=False)`**", ours_estimate, args.repeats, budget)
    add("this PSO: `pso.minimize` on `rl_swarm_costs`", ours_minimize, args.repeats, budget)
    add("this estimator, full: `estimate_field` (+ LM polish)", ours_full, args.repeats,
        budget + " + LM")  # fmt: skip

    if args.pyswarms:

        def with_pyswarms(objective: Callable[[np.ndarray], np.ndarray]) -> Callable[[int], Any]:
            def run(seed: int) -> tuple[float, float]:
                pos, _ = peers.pyswarms_minimize(
                    objective, log_bounds, n_particles=particles, iterations=its, seed=seed
                )
                return float(10.0 ** pos[0]), float(10.0 ** pos[1])

            return run

        # pyswarms evaluates the swarm once per iteration, the initial one included.
        py_budget = f"{particles * its}"
        add("pyswarms `GlobalBestPSO` + compiled `rl_swarm_costs`", with_pyswarms(cost),
            args.repeats, py_budget)  # fmt: skip
        numpy_cost = peers.numpy_field_cost(vf, i_f, dt)
        lfilter_cost = peers.lfilter_field_cost(vf, i_f, dt)
        add("pyswarms `GlobalBestPSO` + numpy objective (loop over samples)",
            with_pyswarms(numpy_cost), args.slow_repeats, py_budget)  # fmt: skip
        add("pyswarms `GlobalBestPSO` + scipy `lfilter` objective (loop over particles)",
            with_pyswarms(lfilter_cost), args.slow_repeats, py_budget)  # fmt: skip

    de_evals = [0]

    def de(seed: int) -> tuple[float, float]:
        r, ell, de_evals[0] = peers.differential_evolution_field(
            cost, log_bounds, population=particles, iterations=its, seed=seed
        )
        return r, ell

    add("scipy `differential_evolution` (vectorized, compiled cost)", de,
        max(3, args.repeats // 3), lambda: str(de_evals[0]))  # fmt: skip

    arx_start = peers.arx_ls_field(vf, i_f, dt)
    lo, hi = 10.0 ** log_bounds[:, 0], 10.0 ** log_bounds[:, 1]
    centre = (math.sqrt(lo[0] * hi[0]), math.sqrt(lo[1] * hi[1]))
    for label, start in (("ARX-LS start", arx_start), ("search-range centre", centre)):
        nfev = [0]

        def lsq(_seed: int, start: tuple[float, float] = start, nfev: list[int] = nfev) -> Any:
            r, ell, nfev[0] = peers.least_squares_field(vf, i_f, dt, start)
            return r, ell

        add(f"scipy `least_squares` (LM) from the {label}", lsq, args.repeats,
            lambda nfev=nfev: f"{nfev[0]} sims")  # fmt: skip
    for name, fn in (
        ("equation error: ARX least squares", peers.arx_ls_field),
        ("equation error: v on [i, di/dt] least squares", peers.derivative_ls_field),
        (f"equation error: ARX recursive LS (λ = {peers.RLS_FORGETTING})", peers.arx_rls_field),
    ):
        add(name, _on_window(fn, vf, i_f, dt), args.repeats, "—")
    return _time_interleaved(methods, bar)


# ---------------------------------------------------------- bias vs noise

FIELD_METHODS = ("this, full", "this, swarm alone", "least_squares", "ARX LS", "derivative LS",
                 "ARX RLS")  # fmt: skip
ARMATURE_METHODS = ("this, full", "this, no EIV comp.", "this, swarm alone", "ARX LS",
                    "derivative LS")  # fmt: skip


def field_methods(w: Window, args: argparse.Namespace) -> dict[str, tuple[float, ...]]:
    """Every field estimator's ``(R, L)`` on ``w`` (this project's first, with its CRLB)."""
    its, particles = args.iterations, args.particles
    full = estimate_field(w.vf, w.i_f, w.dt, n_particles=particles, max_iterations=its,
                          rng=w.seed)  # fmt: skip
    swarm = estimate_field(w.vf, w.i_f, w.dt, n_particles=particles, max_iterations=its,
                           rng=w.seed, polish=False)  # fmt: skip
    arx = peers.arx_ls_field(w.vf, w.i_f, w.dt)
    out: dict[str, tuple[float, ...]] = {
        "this, full": (full.resistance_ohm, full.inductance_h),
        "this, swarm alone": (swarm.resistance_ohm, swarm.inductance_h),
        "least_squares": peers.least_squares_field(w.vf, w.i_f, w.dt, arx)[:2],
        "ARX LS": arx,
        "derivative LS": peers.derivative_ls_field(w.vf, w.i_f, w.dt),
        "ARX RLS": peers.arx_rls_field(w.vf, w.i_f, w.dt),
        "_crlb": (full.std["R"], full.std["L"]),
    }
    return out


def armature_methods(w: Window, args: argparse.Namespace) -> dict[str, tuple[float, ...]]:
    """Every armature estimator's ``(R, L, K)`` on ``w`` (and the CRLB)."""
    its, particles = args.iterations, args.particles

    def ours(**kw: Any) -> CircuitEstimate:
        return estimate_armature(w.va, w.ia, w.i_f, w.omega, w.dt, n_particles=particles,
                                 max_iterations=its, rng=w.seed, **kw)  # fmt: skip

    def rlk(e: CircuitEstimate) -> tuple[float, float, float]:
        return e.resistance_ohm, e.inductance_h, float(e.emf_constant_h or math.nan)

    full = ours()
    return {
        "this, full": rlk(full),
        "this, no EIV comp.": rlk(ours(compensate_input_noise=False)),
        "this, swarm alone": rlk(ours(polish=False, compensate_input_noise=False)),
        "ARX LS": peers.arx_ls_armature(w.va, w.ia, w.i_f, w.omega, w.dt),
        "derivative LS": peers.derivative_ls_armature(w.va, w.ia, w.i_f, w.omega, w.dt),
        "_crlb": (full.std["R"], full.std["L"], full.std["K"]),
    }


def bias_vs_noise(args: argparse.Namespace, bar: tqdm) -> dict[tuple[str, str, float], list[float]]:
    """Relative errors per ``(method, parameter, noise level)`` over seeds, all channels noisy."""
    errors: dict[tuple[str, str, float], list[float]] = {}
    for level in args.levels:
        for seed in range(args.bias_seeds):
            w = p12_window(BIAS_FIRST_SEED + seed, noise=level)
            truth = w.truth
            for method, est in field_methods(w, args).items():
                for name, value in zip(("Rf", "Lf"), est, strict=True):
                    errors.setdefault((method, name, level), []).append(
                        (value - truth[name]) / truth[name]
                    )
            for method, est in armature_methods(w, args).items():
                for name, value in zip(("Ra", "La", "K"), est, strict=True):
                    errors.setdefault((method, name, level), []).append(
                        (value - truth[name]) / truth[name]
                    )
            bar.update(1)
    return errors


# ------------------------------------------------------------ Monte Carlo


def monte_carlo(
    args: argparse.Namespace, case: str, bar: tqdm
) -> tuple[dict[tuple[str, str], list[float]], dict[tuple[str, str], list[float]]]:
    """Errors and normalised errors ``(est - truth) / CRLB`` per ``(method, parameter)``.

    ``case`` "output": noise on the measured field current (field windows) or
    armature current (armature windows) only; "all": ``args.noise`` on every channel.
    """
    errs: dict[tuple[str, str], list[float]] = {}
    zs: dict[tuple[str, str], list[float]] = {}
    full = NoiseLevels.relative(P12, args.noise)
    for seed in range(args.mc_seeds):
        s = MC_FIRST_SEED + seed
        if case == "output":
            wf = p12_window(s, noise=NoiseLevels(i_f=full.i_f))
            wa = p12_window(s, noise=NoiseLevels(ia=full.ia))
        else:
            wf = wa = p12_window(s, noise=full)
        runs = [
            (("Rf", "Lf"), wf.truth, field_methods(wf, args)),
            (("Ra", "La", "K"), wa.truth, armature_methods(wa, args)),
        ]
        if args.pyswarms:
            log_bounds = field_search_range(wf.vf, wf.i_f, wf.dt).log_bounds()

            def cost(x: np.ndarray, w: Window = wf) -> np.ndarray:
                return kernels.rl_swarm_costs(x, w.vf, w.i_f, w.dt, True)

            pos, _ = peers.pyswarms_minimize(
                cost, log_bounds, n_particles=args.particles, iterations=args.iterations, seed=s
            )
            runs[0][2]["pyswarms + compiled cost"] = tuple(float(v) for v in 10.0**pos)
            de = peers.differential_evolution_field(
                cost, log_bounds, population=args.particles, iterations=args.iterations, seed=s
            )
            runs[0][2]["differential_evolution"] = de[:2]
        for names, truth, methods in runs:
            crlb = methods.pop("_crlb")
            for method, est in methods.items():
                for name, value, bound in zip(names, est, crlb, strict=True):
                    errs.setdefault((method, name), []).append(value - truth[name])
                    zs.setdefault((method, name), []).append((value - truth[name]) / bound)
        bar.update(1)
    return errs, zs


def window_study(
    args: argparse.Namespace, bar: tqdm
) -> dict[tuple[int, str], tuple[list[float], list[float]]]:
    """Relative errors and normalised errors of the full estimator against window length.

    Realistic noise on every channel; per length ``(n_samples, parameter) ->
    (errors, errors / CRLB)`` over ``args.window_seeds`` recordings.
    """
    out: dict[tuple[int, str], tuple[list[float], list[float]]] = {}
    for n in args.window_lengths:
        for seed in range(args.window_seeds):
            w = p12_window(WINDOW_FIRST_SEED + seed, noise=args.noise, n_samples=n)
            truth = w.truth
            f = estimate_field(w.vf, w.i_f, w.dt, rng=w.seed)
            a = estimate_armature(w.va, w.ia, w.i_f, w.omega, w.dt, rng=w.seed)
            got = {
                "Rf": (f.resistance_ohm, f.std["R"]),
                "Lf": (f.inductance_h, f.std["L"]),
                "Ra": (a.resistance_ohm, a.std["R"]),
                "La": (a.inductance_h, a.std["L"]),
                "K": (float(a.emf_constant_h or math.nan), a.std["K"]),
            }
            for name, (value, bound) in got.items():
                errs, zs = out.setdefault((n, name), ([], []))
                errs.append((value - truth[name]) / truth[name])
                zs.append((value - truth[name]) / bound)
            bar.update(1)
    return out


# ---------------------------------------------------------------- report


def _pct(x: float) -> str:
    return "nan" if not math.isfinite(x) else f"{100 * x:+.2f} %"


def _ratio(x: float) -> str:
    return f"{x:.1f}×" if math.isfinite(x) else "—"


def render(
    args: argparse.Namespace,
    w: Window,
    rows: list[Timed],
    bias: dict[tuple[str, str, float], list[float]],
    mc: dict[str, tuple[dict[tuple[str, str], list[float]], dict[tuple[str, str], list[float]]]],
    windows: dict[tuple[int, str], tuple[list[float], list[float]]],
    argv: Sequence[str] | None,
    elapsed_s: float,
) -> tuple[str, str]:
    """The markdown report and the short ratio table printed to the terminal."""
    truth = w.truth
    ours = next(r for r in rows if "estimate_field(polish=False)" in r.name)
    bare = next(r for r in rows if "pso.minimize" in r.name)
    kernel = rows[0]
    command = "python -m bench.bench_pso" + ("" if not argv else " " + " ".join(argv))
    budget = f"{args.particles} particles × {args.iterations} iterations"
    lines = [
        "# Benchmarks: this PSO estimator against its peers",
        "",
        f"Made by `{command}` in {elapsed_s:.0f} s on {args.machine}. All methods run "
        "single-threaded in one process (the numba kernels are serial); the machine is shared, "
        "so the load average above is part of the result.",
        "",
        f"Data: a {WINDOW_SAMPLES}-sample window ({WINDOW_SAMPLES / SAMPLE_RATE_HZ:g} s at "
        f"{SAMPLE_RATE_HZ:g} Hz) of a simulated P-12 recording (seed {w.seed}, sensor noise "
        f"{100 * args.noise:g} % of rated on every channel), a quarter window before the first "
        "field-voltage step. Budget: "
        f"{budget}. Every optimiser minimises the same eq. (1) cost over log10(R, L) in the same "
        "data-derived box (`field_search_range`), initial current projected out.",
        "",
        "## 1. Speed of one field estimate",
        "",
        "Wall-clock p50 / p90 / min over timed runs (`time.perf_counter`, after one untimed "
        "warm-up run; the methods are timed round-robin so a change of load hits all alike) and "
        "the median CPU time of the thread (`time.thread_time`: the cost on one core, which the "
        "other users of a shared machine do not inflate). "
        "Ratios: the method's p50 over that of this PSO's `estimate_field(polish=False)` "
        f"({ours.p50_ms:.2f} ms wall, {ours.cpu_p50_ms:.2f} ms CPU), by wall clock and by CPU "
        "time. Errors are "
        "those of the last run's estimate on this window.",
        "",
        "| method | runs | evaluations | p50 (ms) | p90 (ms) | min (ms) | CPU p50 (ms) | "
        "ratio (wall) | ratio (CPU) | Rf error | Lf error |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    short = [f"{'method':<74} {'p50 ms':>9} {'p90 ms':>9} {'x ours':>8}"]
    for r in rows:
        is_kernel = r is kernel
        err_r = math.nan if is_kernel else (r.resistance_ohm - truth["Rf"]) / truth["Rf"]
        err_l = math.nan if is_kernel else (r.inductance_h - truth["Lf"]) / truth["Lf"]
        lines.append(
            f"| {r.name} | {r.times.size} | {r.evaluations} | {r.p50_ms:.3f} | {r.p90_ms:.3f} | "
            f"{r.min_ms:.3f} | {r.cpu_p50_ms:.3f} | "
            f"{_ratio(r.p50_ms / ours.p50_ms)} | {_ratio(r.cpu_p50_ms / ours.cpu_p50_ms)} | "
            f"{'' if is_kernel else _pct(err_r)} | {'' if is_kernel else _pct(err_l)} |"
        )
        plain = r.name.replace("*", "").replace("`", "")
        short.append(
            f"{plain[:74]:<74} {r.p50_ms:9.3f} {r.p90_ms:9.3f} {r.p50_ms / ours.p50_ms:8.2f}"
        )
    calls = args.iterations + 1
    lines += [
        "",
        f"Where the time goes: the cost kernel takes {1e3 * kernel.p50_ms:.0f} µs per "
        f"{args.particles}-particle call on {WINDOW_SAMPLES} samples "
        f"({1e6 * kernel.p50_ms / (args.particles * WINDOW_SAMPLES):.2f} ns per particle-sample), "
        f"so {calls} calls are {kernel.cpu_p50_ms * calls:.2f} ms of the bare PSO's "
        f"{bare.cpu_p50_ms:.2f} ms (CPU time); the swarm's own bookkeeping is the rest.",
        "",
    ]
    # ------------------------------------------------------------ bias table
    lines += [
        "## 2. Bias as noise grows (equation error vs output error)",
        "",
        f"Mean relative error over {args.bias_seeds} seeds per level (each its own recording), "
        "noise on every channel as a fraction of its rated value. Equation error regresses on "
        "the noisy measured current, so its estimates are biased (attenuation), and a numerical "
        "derivative amplifies the noise by 1/dt. Output error compares with the *simulated* "
        "current; only noise on the *inputs* (voltages, and for the armature if·ω) biases it, "
        "which the armature's EIV compensation removes in expectation. Budget as above.",
        "",
    ]
    for circuit, methods, names in (
        ("field", FIELD_METHODS, ("Rf", "Lf")),
        ("armature", ARMATURE_METHODS, ("Ra", "La", "K")),
    ):
        head = [f"{m}: {n}" for m in methods for n in names]
        lines += [
            f"**{circuit}**",
            "",
            "| noise | " + " | ".join(head) + " |",
            "|---|" + "---|" * len(head),
        ]
        for level in args.levels:
            cells = [_pct(float(np.mean(bias[m, n, level]))) for m in methods for n in names]
            lines.append(f"| {100 * level:g} % | " + " | ".join(cells) + " |")
        lines.append("")
    # ------------------------------------------------------------ Monte Carlo
    lines += [
        "## 3. Monte Carlo: RMSE against the Cramér–Rao bound",
        "",
        f"{args.mc_seeds} seeds per case, each its own recording and swarm. "
        "RMSE/CRLB = sqrt(mean(((estimate − truth) / CRLB)²)) over seeds, the CRLB of each seed "
        "being the one-sigma `CircuitEstimate.std` of the full estimator on that window "
        "(Fisher information at the optimum, residual variance from the fit). 1 is efficient. "
        "Bias and RMSE are relative to the truth; 'within' counts seeds inside the target "
        "tolerance (1 % for Rf, Lf, Ra, K; 5 % for La).",
        "",
    ]
    titles = {
        "output": (
            "Noise on the measured currents only (field windows: on if; armature windows: on "
            f"ia; {100 * args.noise:g} % of rated). Output error is maximum likelihood here and "
            "the CRLB is the right yardstick."
        ),
        "all": (
            f"Realistic: {100 * args.noise:g} % of rated on every channel. The input noise makes "
            "this an errors-in-variables problem: the CRLB column is the output-error bound, "
            "shown for scale, not a bound on these estimators."
        ),
    }
    for case, (errs, zs) in mc.items():
        lines += [f"**{titles[case]}**", "",
                  "| method | parameter | bias | RMSE | RMSE/CRLB | max abs error | worst seed "
                  "| within |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for method, name in errs:
            e = np.asarray(errs[method, name]) / truth[name]
            z = np.asarray(zs[method, name])
            tol = TARGET_TOLERANCE[name]
            ok = int(np.sum(np.abs(e) <= tol))
            lines.append(
                f"| {method} | {name} | {_pct(float(np.mean(e)))} | "
                f"{100 * float(np.sqrt(np.mean(e * e))):.3f} % | "
                f"{float(np.sqrt(np.mean(z * z))):.2f} | {100 * float(np.max(np.abs(e))):.3f} % | "
                f"{MC_FIRST_SEED + int(np.argmax(np.abs(e)))} | {ok}/{e.size} |"
            )
        lines.append("")
    # ------------------------------------------------------------ window length
    lines += [
        "## 3b. Accuracy against window length (full estimator, realistic noise)",
        "",
        f"{args.window_seeds} seeds per length, {100 * args.noise:g} % noise on every channel, "
        f"{SAMPLE_RATE_HZ:g} Hz, each window starting a quarter of its length before the first "
        "field step; default swarm (100 × 100) + polish + EIV compensation. Cells: RMSE "
        "(relative) / seeds within the target tolerance.",
        "",
        "| window | " + " | ".join(("Rf", "Lf", "Ra", "La", "K")) + " |",
        "|---|---|---|---|---|---|",
    ]
    for n in args.window_lengths:
        cells = []
        for name in ("Rf", "Lf", "Ra", "La", "K"):
            e = np.asarray(windows[n, name][0])
            ok = int(np.sum(np.abs(e) <= TARGET_TOLERANCE[name]))
            cells.append(f"{100 * float(np.sqrt(np.mean(e * e))):.2f} % / {ok}/{e.size}")
        lines.append(f"| {n} samples ({n / SAMPLE_RATE_HZ:g} s) | " + " | ".join(cells) + " |")
    lines.append("")
    # ------------------------------------------------------------ targets
    lines += _targets(args, rows, ours, bare, kernel, mc, windows, truth)
    return "\n".join(lines) + "\n", "\n".join(short)


def _targets(
    args: argparse.Namespace,
    rows: list[Timed],
    ours: Timed,
    bare: Timed,
    kernel: Timed,
    mc: dict[str, tuple[dict[tuple[str, str], list[float]], dict[tuple[str, str], list[float]]]],
    windows: dict[tuple[int, str], tuple[list[float], list[float]]],
    truth: dict[str, float],
) -> list[str]:
    def verdict(ok: bool) -> str:
        return "**met**" if ok else "**missed**"

    out = ["## 4. Targets of issue 2", ""]
    budget_note = (
        "" if (args.particles, args.iterations) == (100, 100)
        else f" (this run's budget is {args.particles} × {args.iterations}, not 100 × 100)"
    )  # fmt: skip
    out.append(
        f"- Median of one 100 × 100 estimate on 2000 samples ≤ {TARGET_MEDIAN_MS:g} ms"
        f"{budget_note}: `estimate_field(polish=False)` p50 {ours.p50_ms:.2f} ms, "
        f"`pso.minimize` p50 {bare.p50_ms:.2f} ms — {verdict(ours.p50_ms <= TARGET_MEDIAN_MS)} "
        f"(wall clock; fastest of the {ours.times.size} runs {ours.min_ms:.2f} ms). "
        f"CPU time of the thread: p50 {ours.cpu_p50_ms:.2f} ms "
        f"({'within' if ours.cpu_p50_ms <= TARGET_MEDIAN_MS else 'over'} the target; the gap to "
        "the wall clock is the other processes on the shared machine). The cost kernel alone "
        f"accounts for {kernel.cpu_p50_ms * (args.iterations + 1):.2f} ms (CPU) of it."
    )
    py_numpy = [r for r in rows if r.name.startswith("pyswarms") and "compiled" not in r.name]
    py_comp = [r for r in rows if r.name.startswith("pyswarms") and "compiled" in r.name]
    kernel_ms = kernel.cpu_p50_ms * (args.iterations + 1)
    if py_numpy:
        fastest = min(py_numpy, key=lambda r: r.p50_ms)
        ratio = fastest.p50_ms / ours.p50_ms
        cpu_ratio = fastest.cpu_p50_ms / ours.cpu_p50_ms
        ok = min(ratio, cpu_ratio) >= TARGET_VS_PYSWARMS_NUMPY
        out.append(
            f"- ≥ {TARGET_VS_PYSWARMS_NUMPY:g}× faster than pyswarms with a numpy objective "
            f"(the faster of the two numpy/scipy objectives): {ratio:.1f}× by wall clock, "
            f"{cpu_ratio:.1f}× by CPU time — {verdict(ok)}."
        )
    if py_comp:
        ratio = py_comp[0].p50_ms / ours.p50_ms
        cpu_ratio = py_comp[0].cpu_p50_ms / ours.cpu_p50_ms
        bound = py_comp[0].cpu_p50_ms / kernel_ms
        out.append(
            f"- ≥ {TARGET_VS_PYSWARMS_COMPILED:g}× faster than pyswarms with the same compiled "
            f"cost: {ratio:.1f}× by wall clock, {cpu_ratio:.1f}× by CPU time — "
            f"{verdict(min(ratio, cpu_ratio) >= TARGET_VS_PYSWARMS_COMPILED)}. Both spend the "
            f"same {kernel_ms:.2f} ms (CPU) in the kernel; pyswarms adds "
            f"{py_comp[0].cpu_p50_ms - kernel_ms:.2f} ms of its own, this PSO "
            f"{ours.cpu_p50_ms - kernel_ms:.2f} ms. Even with no overhead at all, a PSO on this "
            f"kernel could be at most {bound:.1f}× faster than pyswarms: the target needs a "
            "faster kernel (which helps both) more than a leaner swarm."
        )
    if not args.pyswarms:
        out.append("- pyswarms targets: not measured (pyswarms not installed or skipped).")
    errs, _ = mc["all"]
    parts = []
    all_ok = True
    for name in ("Rf", "Lf", "Ra", "La", "K"):
        e = np.abs(np.asarray(errs["this, full", name]) / truth[name])
        n_ok = int(np.sum(e <= TARGET_TOLERANCE[name]))
        all_ok &= n_ok == e.size
        parts.append(
            f"{name} {n_ok}/{e.size} within {100 * TARGET_TOLERANCE[name]:g} % "
            f"(max {100 * float(e.max()):.2f} %)"
        )
    out.append(
        f"- Within 1 % (Rf, Lf, Ra, K) and 5 % (La) at realistic noise "
        f"({100 * args.noise:g} % on every channel), full estimator: "
        + "; ".join(parts)
        + f" — {verdict(all_ok)}."
    )
    if not all_ok:
        la = np.asarray(errs["this, full", "La"]) / truth["La"]
        longest = max(args.window_lengths)
        e = np.asarray(windows[longest, "La"][0])
        n_ok = int(np.sum(np.abs(e) <= TARGET_TOLERANCE["La"]))
        out.append(
            f"  La on {WINDOW_SAMPLES}-sample windows: bias {100 * float(np.mean(la)):+.2f} %, "
            f"RMSE {100 * float(np.sqrt(np.mean(la * la))):.2f} % (section 3). On "
            f"{longest}-sample windows (section 3b): RMSE "
            f"{100 * float(np.sqrt(np.mean(e * e))):.2f} %, {n_ok}/{e.size} seeds within 5 %."
        )
    _, zs = mc["output"]
    parts = []
    all_ok = True
    for name in ("Rf", "Lf", "Ra", "La", "K"):
        z = np.asarray(zs["this, full", name])
        ratio = float(np.sqrt(np.mean(z * z)))
        all_ok &= ratio <= TARGET_RMSE_CRLB
        parts.append(f"{name} {ratio:.2f}")
    out.append(
        f"- RMSE/CRLB ≤ {TARGET_RMSE_CRLB:g} (output noise only, full estimator): "
        + ", ".join(parts) + f" — {verdict(all_ok)}."
    )  # fmt: skip
    return out + [""]


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    args.machine = machine_description()  # the load average before this run adds its own
    started = time.perf_counter()
    w = p12_window(args.seed, noise=args.noise)
    n_timing = 10 + (3 if args.pyswarms else 0)
    total = (
        n_timing
        + len(args.levels) * args.bias_seeds
        + 2 * args.mc_seeds
        + len(args.window_lengths) * args.window_seeds
    )
    with tqdm(total=total, desc="benchmark", disable=args.no_progress, file=sys.stderr) as bar:
        rows = timing(w, args, bar)
        bias = bias_vs_noise(args, bar)
        mc = {case: monte_carlo(args, case, bar) for case in ("output", "all")}
        windows = window_study(args, bar)
    text, short = render(
        args, w, rows, bias, mc, windows, argv if argv is not None else sys.argv[1:],
        time.perf_counter() - started,
    )  # fmt: skip
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text, encoding="utf-8")
    print(short)
    print()
    print("\n".join(line for line in text.splitlines() if line.startswith("- ")))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
