"""The swarm cost kernel against the core's FMA peak, and this PSO against pyswarms on it.

Same process, same data, timed round-robin so a change of load on the shared
machine hits every method alike:

1. **clock**: a chain of dependent FMAs (4 cycles each on Zen 3 and on every
   Intel core since Skylake) timed between the kernel runs gives the cycles the
   core really ran at, turbo and all;
2. **kernel**: :func:`~observer.estimation.intersample_kernels.moment_swarm_costs`
   (the fast kernel every estimate uses) and its plain reference
   :func:`~observer.estimation.intersample_kernels.plain_moment_swarm_costs`
   on the windows the observer sees (10 kHz, 1 s: 10 000 samples), in
   particle-samples per cycle against the peak: two FMA pipes of four doubles
   (AVX2) make 8 FMA lanes per cycle, divided by the FMAs one particle-sample
   needs in that loop (5 for the field with a held voltage, 13 for the
   armature with ``K`` fitted and a three-moment EMF);
3. **float32**: the same kernel on float32 samples (eight lanes a vector),
   timed with the others, and what it does to the estimate: windows of a
   12-bit ADC recording minimised in float64 and float32, the difference
   against the spread the sensor noise gives;
4. **assembly**: each particle block's loop compiled afresh in a one-call
   wrapper (the cache cannot be inspected) and its packed (ymm) FMAs counted:
   one per FMA of a block's sample, and no scalar ones;
5. **swarm**: this project's PSO (``pso.minimize``) against pyswarms'
   ``GlobalBestPSO`` on the very same compiled cost and budget.

Run ``python -m bench.kernel_speed --help``; the figures go to stdout and, as
markdown, to ``--output``.
"""

from __future__ import annotations

import argparse
import functools
import math
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from bench import peers
from bench.common import machine_description, p12_window
from observer.estimation import intersample_kernels as ik
from observer.estimation import pso
from observer.estimation.armature import armature_problem
from observer.estimation.problem import WindingProblem, make_problem
from observer.estimation.ranges import armature_search_range, field_search_range

#: FMA lanes per cycle of one core: two FMA pipes, four doubles each (AVX2).
PEAK_FMA_LANES_PER_CYCLE = 8
#: Latency (cycles) of one double FMA: Zen 3, and Intel since Skylake.
FMA_LATENCY_CYCLES = 4
#: Dependent FMAs per clock measurement (about 0.5 ms).
CLOCK_CHAIN = 400_000
#: Target of the issue: the dominant kernel at >= this share of the peak.
TARGET_SHARE_OF_PEAK = 0.5
TARGET_VS_PYSWARMS = 3.0


@njit(fastmath={"contract"}, cache=True)
def _fma_chain(n: int, x: float) -> float:
    """``n`` dependent FMAs: takes ``n * FMA_LATENCY_CYCLES`` cycles."""
    b = 1.0000001
    c = 1e-9
    for _ in range(n):
        x = x * b + c
    return x


def measure_clock_ghz() -> float:
    """The core's clock (GHz) over one FMA chain (the thread's CPU time: preemption left out)."""
    t0 = time.thread_time()
    _fma_chain(CLOCK_CHAIN, 1.0)
    return CLOCK_CHAIN * FMA_LATENCY_CYCLES / (time.thread_time() - t0) / 1e9


@dataclass
class Case:
    """One kernel configuration the observer runs."""

    name: str
    problem: WindingProblem
    log_bounds: np.ndarray
    noise_var: float
    n_particles: int

    def args(self, x: np.ndarray) -> tuple[object, ...]:
        p = self.problem
        seg = p.segments
        k = 0.0 if p.emf_constant is None else float(p.emf_constant)
        return (x, p.inp.mu, p.mu_emf, p.current, seg.starts, seg.ends, p.dt, True,
                p.emf_mode, k, self.noise_var)  # fmt: skip

    def args32(self, x: np.ndarray) -> tuple[object, ...]:
        """:meth:`args` with the samples' arrays in float32 (the float32 path)."""
        a = list(self.args(x))
        for i in (1, 2, 3):
            a[i] = np.ascontiguousarray(a[i], dtype=np.float32)
        return tuple(a)

    @functools.cached_property
    def n_moments(self) -> int:
        # Cached: it scans the window (~40-80 us), which must not be timed with the kernel.
        p = self.problem
        extra = p.inp.mu[:, 1:].any() or (p.emf is not None and p.mu_emf[:, 1:].any())
        return 3 if extra else 1

    @property
    def fmas(self) -> int:
        key = (self.problem.fits_k, self.n_moments)
        return ik.FMAS_PER_PARTICLE_SAMPLE[key]


def make_cases(n_samples: int, rate_hz: float, particles: Sequence[int]) -> list[Case]:
    """The kernel calls of a window: field, armature, its EIV re-run, at each swarm size."""
    w = p12_window(0, n_samples=n_samples, sample_rate_hz=rate_hz)
    f_box = field_search_range(w.vf, w.i_f, w.dt).log_bounds()
    a_box = armature_search_range(w.va, w.ia, w.i_f, w.omega, w.dt).log_bounds()
    field_hold = make_problem(w.vf, w.i_f, w.dt, "hold")
    field_smooth = make_problem(w.vf, w.i_f, w.dt, "smooth")
    arm = armature_problem(w.va, w.ia, w.i_f, w.omega, w.dt, intersample="hold")
    arm_held = armature_problem(
        w.va, w.ia, w.i_f, w.omega, w.dt, intersample="hold", emf_constant=1.12
    )
    cases = []
    for n in particles:
        cases += [
            Case("field, held voltage", field_hold, f_box, 0.0, n),
            Case("field, smooth voltage (3 moments)", field_smooth, f_box, 0.0, n),
            Case("armature, K fitted (EMF: 3 moments)", arm, a_box, 0.0, n),
            Case("armature, K fitted, EIV compensated", arm, a_box, 0.3, n),
            Case("armature, K held", arm_held, a_box, 0.0, n),
        ]
    return cases


@dataclass
class KernelTiming:
    case: Case
    plain_s: list[float]
    fast_s: list[float]
    f32_s: list[float]
    max_rel_diff: float
    f32_rel_diff: float


def time_kernels(
    cases: list[Case], repeats: int, batch: int, rng: np.random.Generator
) -> tuple[list[KernelTiming], list[float]]:
    """Plain, fast and float32 kernel times (s per call) of every case, and the clocks (GHz)."""
    xs = [rng.uniform(c.log_bounds[:, 0], c.log_bounds[:, 1], (c.n_particles, 2)) for c in cases]
    out = []
    for c, x in zip(cases, xs, strict=True):
        plain = ik.plain_moment_swarm_costs(*c.args(x))  # compiles or loads
        fast = ik.moment_swarm_costs(*c.args(x), c.n_moments)
        f32 = ik.moment_swarm_costs(*c.args32(x), c.n_moments)
        scale = max(np.max(np.abs(plain)), 1e-13 * float(c.problem.current @ c.problem.current))
        diff = float(np.max(np.abs(fast - plain)) / scale)
        out.append(KernelTiming(c, [], [], [], diff, float(np.max(np.abs(f32 - plain)) / scale)))
    clocks = []
    _fma_chain(10, 1.0)
    for _ in range(repeats):
        for t, x in zip(out, xs, strict=True):
            clocks.append(measure_clock_ghz())
            args, args32, moments = t.case.args(x), t.case.args32(x), t.case.n_moments
            runs: list[tuple[Callable[..., object], tuple[object, ...], list[float]]] = [
                (ik.plain_moment_swarm_costs, args, t.plain_s),
                (ik.moment_swarm_costs, (*args, moments), t.fast_s),
                (ik.moment_swarm_costs, (*args32, moments), t.f32_s),
            ]
            for kernel, kernel_args, times in runs:
                t0 = time.thread_time()
                for _ in range(batch):
                    kernel(*kernel_args)
                times.append((time.thread_time() - t0) / batch)
    return out, clocks


# ---------------------------------------------------------------- float32 against the noise


@dataclass
class Float32Error:
    """What the float32 path changes in one circuit's estimate, against what the noise does."""

    circuit: str
    seeds: int
    #: Spread (std over noise seeds) of the float64 estimate, relative, per parameter.
    noise_spread: dict[str, float]
    #: Largest float32-float64 difference of the estimate over the seeds, relative.
    f32_shift: dict[str, float]
    #: Largest |cost32 - cost64| at the float64 minimum, in units of the residual
    #: variance (cost/n): a difference of 1 is what one standard error of the fit costs.
    cost_error_chi2: float
    #: Largest cost at the minimum relative to the sum of squared currents: the share
    #: of the kernel's sums (before i0 and K are projected out) that the fit keeps.
    residual_share: float

    @property
    def below_noise(self) -> bool:
        """Float32 moves the estimate by under a tenth of the noise spread, the cost by 0.1."""
        worst = max(self.f32_shift[n] / self.noise_spread[n] for n in self.noise_spread)
        return worst < 0.1 and self.cost_error_chi2 < 0.1


def float32_errors(n_samples: int, rate_hz: float, seeds: int, adc_bits: int) -> list[Float32Error]:
    """Minimise each circuit's cost in float64 and float32 on ``seeds`` noisy windows.

    Every window is a P-12 recording through a ``adc_bits``-bit ADC with 0.2 %
    sensor noise. Both minimisations start where a float64 swarm ended and run
    Nelder-Mead to its tolerance floor, so they differ only by the kernel's
    arithmetic; the spread of the float64 minimum over the seeds is the noise's.
    """
    from scipy.optimize import minimize as scipy_minimize

    rows = []
    for circuit in ("field", "armature"):
        best64, best32, chi2, share = [], [], [], []
        for seed in range(seeds):
            w = p12_window(seed, n_samples=n_samples, sample_rate_hz=rate_hz, adc_bits=adc_bits)
            if circuit == "field":
                problem = make_problem(w.vf, w.i_f, w.dt, "hold")
                box = field_search_range(w.vf, w.i_f, w.dt).log_bounds()
            else:
                problem = armature_problem(w.va, w.ia, w.i_f, w.omega, w.dt, intersample="hold")
                box = armature_search_range(w.va, w.ia, w.i_f, w.omega, w.dt).log_bounds()
            case = Case(circuit, problem, box, 0.0, 1)

            def cost64(x: np.ndarray, case: Case = case) -> float:
                return float(ik.moment_swarm_costs(*case.args(x[None, :]), case.n_moments)[0])

            def cost32(x: np.ndarray, case: Case = case) -> float:
                return float(ik.moment_swarm_costs(*case.args32(x[None, :]), case.n_moments)[0])

            swarm = problem.swarm_cost()
            start = pso.minimize(swarm, box, n_particles=40, max_iterations=60, rng=seed).x
            options = {"xatol": 1e-12, "fatol": 0.0, "maxiter": 4000, "maxfev": 8000}
            x64 = scipy_minimize(cost64, start, method="Nelder-Mead", options=options).x
            x32 = scipy_minimize(cost32, start, method="Nelder-Mead", options=options).x
            best64.append(10.0**x64)
            best32.append(10.0**x32)
            residual_var = cost64(x64) / problem.current.size
            chi2.append(abs(cost32(x64) - cost64(x64)) / residual_var)
            share.append(cost64(x64) / float(problem.current @ problem.current))
        b64, b32 = np.array(best64), np.array(best32)
        names = ("Rf", "Lf") if circuit == "field" else ("Ra", "La")
        mean = b64.mean(axis=0)
        rows.append(
            Float32Error(
                circuit,
                seeds,
                {n: float(b64[:, i].std(ddof=1) / mean[i]) for i, n in enumerate(names)},
                {
                    n: float(np.max(np.abs(b32[:, i] - b64[:, i])) / mean[i])
                    for i, n in enumerate(names)
                },  # fmt: skip
                float(np.max(chi2)),
                float(np.max(share)),
            )
        )
    return rows


# ---------------------------------------------------------------- assembly

_FMA = re.compile(r"\bvf(?:n?m)(?:add|sub)\d{3}pd\s+[^\n]*?%ymm")
_SCALAR_FMA = re.compile(r"\bvf(?:n?m)(?:add|sub)\d{3}sd\b")


def packed_fmas() -> dict[str, tuple[int, int, int]]:
    """Packed (ymm) and scalar FMAs in each block's compiled loop, and the packed FMAs one
    sample of the block needs (one per FMA of each of its vectors)."""
    n = 64
    mu = np.ones((n - 1, 3))
    y = np.ones(n)
    w = np.ones((ik._ROWS, 8))
    blocks: list[tuple[str, Callable[..., None], bool, int]] = [
        ("_plain_hold_block", ik._plain_hold_block, False, 1),
        ("_plain_moments_block", ik._plain_moments_block, False, 3),
        ("_fit_hold_block", ik._fit_hold_block, True, 1),
        ("_fit_moments_block", ik._fit_moments_block, True, 3),
    ]
    out = {}
    for name, block, fit, moments in blocks:

        def one_block(w, y, mu, mu_emf, block=block):  # type: ignore[no-untyped-def]
            block(w, y, mu, mu_emf, 0, 0, y.shape[0] - 1)

        fresh = njit(one_block)
        fresh(w, y, mu, mu)
        asm = fresh.inspect_asm(fresh.signatures[0])  # type: ignore[attr-defined]
        expected = ik.FMAS_PER_PARTICLE_SAMPLE[(fit, moments)] * ik.BLOCK_VECTORS[fit]
        out[name] = (len(_FMA.findall(asm)), len(_SCALAR_FMA.findall(asm)), expected)
    return out


# ---------------------------------------------------------------- swarm vs pyswarms


@dataclass
class SwarmTiming:
    name: str
    times: list[float]
    cost: float


def time_swarms(
    case: Case, particles: int, iterations: int, repeats: int, with_pyswarms: bool
) -> tuple[list[SwarmTiming], float]:
    """This PSO and pyswarms on ``case``'s compiled cost; also the kernel's time per call."""
    cost = case.problem.swarm_cost(case.noise_var)
    box = case.log_bounds
    x = np.random.default_rng(0).uniform(box[:, 0], box[:, 1], (particles, 2))

    def ours(seed: int) -> float:
        res = pso.minimize(cost, box, n_particles=particles, max_iterations=iterations, rng=seed)
        return res.cost

    def theirs(seed: int) -> float:
        # pyswarms evaluates the initial swarm as its first iteration: one more
        # iteration gives it the same number of evaluations as this PSO.
        _, best = peers.pyswarms_minimize(
            cost, box, n_particles=particles, iterations=iterations + 1, seed=seed
        )
        return best

    def kernel(_seed: int) -> float:
        for _ in range(iterations + 1):
            cost(x)
        return math.nan

    methods: list[tuple[str, Callable[[int], float]]] = [
        ("cost kernel alone, same calls", kernel),
        ("this PSO: `pso.minimize`", ours),
    ]
    if with_pyswarms:
        methods.append(("pyswarms `GlobalBestPSO`", theirs))
    rows = [SwarmTiming(name, [], math.nan) for name, _ in methods]
    for _, run in methods:
        run(10_000)  # warm-up
    for i in range(repeats):
        for (_, run), row in zip(methods, rows, strict=True):
            t0 = time.thread_time()
            row.cost = run(i)
            row.times.append(time.thread_time() - t0)
    kernel_call = float(np.min(rows[0].times)) / (iterations + 1)
    return rows, kernel_call


# ---------------------------------------------------------------- report


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.kernel_speed",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--samples", type=int, default=10_000, help="window length (samples)")
    parser.add_argument("--rate", type=float, default=10_000.0, help="sample rate (Hz)")
    parser.add_argument(
        "--particles", type=str, default="24,100", help="swarm sizes of the kernel table"
    )
    parser.add_argument("--repeats", type=int, default=15, help="timed rounds")
    parser.add_argument("--batch", type=int, default=5, help="kernel calls per timed run")
    parser.add_argument("--swarm-samples", type=int, default=2000,
                        help="window of the swarm race (2000 at 2 kHz: the issue's)")  # fmt: skip
    parser.add_argument("--swarm-particles", type=int, default=100)
    parser.add_argument("--swarm-iterations", type=int, default=100)
    parser.add_argument("--swarm-repeats", type=int, default=15)
    parser.add_argument("--skip-pyswarms", action="store_true")
    parser.add_argument("--f32-seeds", type=int, default=6,
                        help="noisy windows of the float32 error study")  # fmt: skip
    parser.add_argument("--adc-bits", type=int, default=12,
                        help="ADC resolution of the float32 error study's recordings")  # fmt: skip
    parser.add_argument("--quick", action="store_true", help="smoke run: few repeats, short window")
    parser.add_argument("--output", type=Path, default=Path("docs/kernel_speed.md"))
    args = parser.parse_args(argv)
    try:
        args.particle_counts = [int(p) for p in args.particles.split(",") if p.strip()]
    except ValueError:
        parser.error(f"--particles must be comma-separated integers, got {args.particles!r}")
    if not args.particle_counts or min(args.particle_counts) < 1:
        parser.error("--particles needs at least one swarm size >= 1")
    if args.quick:
        args.samples = min(args.samples, 2000)
        args.rate = 2000.0
        args.repeats = min(args.repeats, 2)
        args.batch = 1
        args.swarm_iterations = min(args.swarm_iterations, 10)
        args.swarm_repeats = 2
        args.f32_seeds = min(args.f32_seeds, 2)
    if not 2 <= args.adc_bits <= 31:
        parser.error(f"--adc-bits must be from 2 to 31, got {args.adc_bits}")
    if args.f32_seeds < 2:
        parser.error("--f32-seeds must be at least 2 (the noise spread is a standard deviation)")
    for name in ("samples", "repeats", "batch", "swarm_samples", "swarm_particles",
                 "swarm_iterations", "swarm_repeats"):  # fmt: skip
        if getattr(args, name) < (100 if "samples" in name else 1):
            parser.error(f"--{name.replace('_', '-')} is too small")
    args.pyswarms = not args.skip_pyswarms and peers.pyswarms_available()
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_description()
    started = time.perf_counter()
    rng = np.random.default_rng(1)
    cases = make_cases(args.samples, args.rate, args.particle_counts)
    kernel_rows, clocks = time_kernels(cases, args.repeats, args.batch, rng)
    ghz = float(np.max(clocks))  # the least disturbed measurement
    asm = packed_fmas()
    f32_rows = float32_errors(args.samples, args.rate, args.f32_seeds, args.adc_bits)
    swarm_case = make_cases(args.swarm_samples, 2000.0, [args.swarm_particles])[0]
    swarm_rows, kernel_call = time_swarms(
        swarm_case, args.swarm_particles, args.swarm_iterations, args.swarm_repeats, args.pyswarms
    )
    elapsed = time.perf_counter() - started

    command = "python -m bench.kernel_speed" + ("" if not argv else " " + " ".join(argv))
    lines = [
        "# The swarm cost kernel against the FMA peak",
        "",
        f"Made by `{command}` in {elapsed:.0f} s on {machine}. Shared machine: every time is "
        "the CPU time of the benchmark's thread (`time.thread_time`: what other processes do "
        "not inflate by preempting it), kernels the fastest of the timed rounds, and every ratio "
        "compares methods timed round-robin in the same run.",
        "",
        f"Clock: {ghz:.2f} GHz (fastest of {len(clocks)} chains of {CLOCK_CHAIN} dependent FMAs, "
        f"at {FMA_LATENCY_CYCLES} cycles each; median {float(np.median(clocks)):.2f} GHz). Peak: "
        f"{PEAK_FMA_LANES_PER_CYCLE} FMA lanes per cycle (two FMA pipes x four doubles, AVX2), "
        "so a loop of N FMAs per particle-sample peaks at 8/N particle-samples per cycle.",
        "",
        f"## Kernel: one swarm's cost on a {args.samples}-sample window ({args.rate:g} Hz)",
        "",
        "| case | particles | FMAs / particle-sample | peak (p-s/cycle) | plain (µs) | fast (µs) "
        "| speed-up | fast (p-s/cycle) | share of peak | max rel. difference |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    short = []
    for r in kernel_rows:
        c = r.case
        plain_s, fast_s = float(np.min(r.plain_s)), float(np.min(r.fast_s))
        ps = c.n_particles * args.samples
        per_cycle = ps / (fast_s * ghz * 1e9)
        peak = PEAK_FMA_LANES_PER_CYCLE / c.fmas
        lines.append(
            f"| {c.name} | {c.n_particles} | {c.fmas} | {peak:.2f} | {1e6 * plain_s:.0f} | "
            f"{1e6 * fast_s:.0f} | {plain_s / fast_s:.1f}× | {per_cycle:.2f} | "
            f"{100 * per_cycle / peak:.0f} % | {r.max_rel_diff:.1e} |"
        )
        short.append(
            f"{c.name:<40} P={c.n_particles:<4} fast {1e6 * fast_s:7.0f} us  "
            f"{per_cycle:5.2f} p-s/cycle = {100 * per_cycle / peak:3.0f} % of peak "
            f"({plain_s / fast_s:.1f}x plain)"
        )
    lines += [
        "",
        "Max rel. difference: fast against plain kernel, relative to the largest cost (or, for "
        "a fitted K, to 1e-13·Σy²: the sums K's projection subtracts). "
        "The padding of a swarm to whole blocks (four particles with K fitted, eight without) "
        "is counted as waste (24 is whole; 100 is padded to 104 without K fitted).",
        "",
        "## Float32 path: the same kernel on float32 samples (eight lanes a vector)",
        "",
        "Peak: 16 float32 FMA lanes per cycle, so 16/N particle-samples per cycle.",
        "",
        "| case | particles | float64 (µs) | float32 (µs) | speed-up | float32 (p-s/cycle) "
        "| share of float32 peak | max rel. difference |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in kernel_rows:
        c = r.case
        fast_s, f32_s = float(np.min(r.fast_s)), float(np.min(r.f32_s))
        per_cycle = c.n_particles * args.samples / (f32_s * ghz * 1e9)
        peak32 = 2 * PEAK_FMA_LANES_PER_CYCLE / c.fmas
        lines.append(
            f"| {c.name} | {c.n_particles} | {1e6 * fast_s:.0f} | {1e6 * f32_s:.0f} | "
            f"{fast_s / f32_s:.2f}× | {per_cycle:.2f} | {100 * per_cycle / peak32:.0f} % | "
            f"{r.f32_rel_diff:.1e} |"
        )
        short.append(
            f"{c.name:<40} P={c.n_particles:<4} float32 {1e6 * f32_s:7.0f} us "
            f"({fast_s / f32_s:.2f}x float64), rel. difference {r.f32_rel_diff:.1e}"
        )
    lines += [
        "",
        f"What float32 changes in the estimate, against the sensor noise: {f32_rows[0].seeds} "
        f"windows of the P-12 ({args.samples} samples at {args.rate:g} Hz, 0.2 % sensor noise, "
        f"{args.adc_bits}-bit ADC at 2.5× rated), each minimised in float64 and in float32 "
        "(Nelder-Mead from where a float64 swarm ended, to its tolerance floor). Noise spread: "
        "the standard deviation of the float64 estimate over the windows; float32 shift: the "
        "largest difference between the two estimates of a window; cost error: the largest "
        "|cost32 − cost64| at the float64 minimum in units of cost/n (1 = what one standard "
        "error of the fit costs); residual share: the cost at the minimum over Σy², what is "
        "left of the kernel's sums once the initial current (and K) are projected out.",
        "",
        "| circuit | parameter | noise spread | float32 shift | shift / spread "
        "| cost error (cost/n) | residual share |",
        "|---|---|---|---|---|---|---|",
    ]
    for e in f32_rows:
        for name, spread in e.noise_spread.items():
            shift = e.f32_shift[name]
            lines.append(
                f"| {e.circuit} | {name} | {100 * spread:.3f} % | {100 * shift:.2g} % | "
                f"{shift / spread:.2g} | {e.cost_error_chi2:.2g} | {e.residual_share:.1e} |"
            )
            short.append(
                f"float32 {name}: shift {100 * shift:.2g} % against noise {100 * spread:.3f} % "
                f"(cost error {e.cost_error_chi2:.2g} cost/n)"
            )
    lines += [
        "",
        "## Assembly: packed FMAs in each block's loop",
        "",
        "| block | ymm FMAs found | scalar FMAs found | ymm FMAs of one sample of a block "
        "| samples per compiled pass |",
        "|---|---|---|---|---|",
    ]
    for name, (found, scalar, needed) in asm.items():
        passes = (
            f"{found // needed}" if found % needed == 0 else f"{found / needed:.2f} (not whole)"
        )
        lines.append(f"| `{name}` | {found} | {scalar} | {needed} | {passes} |")
        short.append(
            f"asm {name}: {found} ymm FMAs, {scalar} scalar (one sample of a block needs {needed})"
        )
    budget = f"{args.swarm_particles} particles × {args.swarm_iterations} iterations"
    lines += [
        "",
        f"## Swarm: {budget} on the field's compiled cost ({args.swarm_samples} samples at "
        "2 kHz, held voltage)",
        "",
        "| method | runs | CPU p50 (ms) | CPU min (ms) | × this PSO (p50) | best cost |",
        "|---|---|---|---|---|---|",
    ]
    ours = swarm_rows[1]
    for row in swarm_rows:
        p50 = float(np.median(row.times))
        lines.append(
            f"| {row.name} | {len(row.times)} | {1e3 * p50:.2f} | {1e3 * min(row.times):.2f} | "
            f"{p50 / float(np.median(ours.times)):.2f} | {row.cost:.6g} |"
        )
        short.append(f"{row.name:<40} p50 {1e3 * p50:7.2f} ms")
    lines.append("")
    lines += ["## Targets of issue 12", ""]
    for n_particles in args.particle_counts:
        # The case that costs most at this swarm size (time x FMAs: the armature's).
        dominant = max(
            (r for r in kernel_rows if r.case.n_particles == n_particles),
            key=lambda r: float(np.min(r.fast_s)) * r.case.fmas,
        )
        best = n_particles * args.samples / (float(np.min(dominant.fast_s)) * ghz * 1e9)
        share = best / (PEAK_FMA_LANES_PER_CYCLE / dominant.case.fmas)
        lines.append(
            f"- Dominant kernel at {n_particles} particles ({dominant.case.name}) at "
            f"≥ {100 * TARGET_SHARE_OF_PEAK:g} % of the FMA peak: {100 * share:.0f} % — "
            f"{'**met**' if share >= TARGET_SHARE_OF_PEAK else '**missed**'}."
        )
    for e in f32_rows:
        verdict = "below the noise: usable" if e.below_noise else "above the noise: not used"
        worst = max(e.f32_shift[n] / e.noise_spread[n] for n in e.noise_spread)
        lines.append(
            f"- Float32 path, {e.circuit}: {verdict} (estimate shifted by up to {worst:.2g}× the "
            f"noise spread, cost by {e.cost_error_chi2:.2g} cost/n; threshold 0.1 of either)."
        )
    if len(swarm_rows) == 3:
        ratio = float(np.median(swarm_rows[2].times)) / float(np.median(ours.times))
        lines.append(
            f"- ≥ {TARGET_VS_PYSWARMS:g}× faster than pyswarms on the same compiled cost: "
            f"{ratio:.1f}× — {'**met**' if ratio >= TARGET_VS_PYSWARMS else '**missed**'} "
            f"(the kernel takes {1e3 * kernel_call * (args.swarm_iterations + 1):.2f} ms of "
            "either; the rest is each swarm's own work)."
        )
        short.append(f"pyswarms / this PSO: {ratio:.2f}x")
    else:
        lines.append("- pyswarms: not measured (not installed or skipped).")
    text = "\n".join(lines) + "\n"
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text, encoding="utf-8")
    print(f"clock {ghz:.2f} GHz (median {float(np.median(clocks)):.2f})")
    print("\n".join(short))
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
