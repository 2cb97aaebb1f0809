"""Regenerate the paper's table and convergence figure on simulated P-12 data.

The paper estimates the field (Rf, Lf) and armature (Ra, La) of a P-12 motor
with its PSO in two options: A, 100 particles and 100, 500 or 1000 iterations;
B, 500 iterations and 50, 100 or 200 particles. This script runs the same grid
on windows of simulated P-12 recordings (the simulator uses the paper's values
as the truth) and writes a markdown table with the paper's numbers alongside:

* **swarm alone** -- ``polish=False`` (and ``compensate_input_noise=False`` for
  the armature): what the PSO itself reaches, as in the paper's table;
* **full estimator** -- the same swarm followed by Levenberg-Marquardt polish
  and, for the armature, the errors-in-variables compensation.

Each cell is the median over seeds (each seed: its own recording and swarm)
with the range over seeds. The figure shows the swarm's best cost against
iteration for the paper's four coefficient schedules, as excess over the
window's minimum, averaged over seeds.

Run ``python -m bench.paper_table --help``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bench.common import (
    PAPER_COLUMNS,
    PAPER_ESTIMATES,
    PAPER_GIVEN,
    SAMPLE_RATE_HZ,
    WINDOW_SAMPLES,
    Window,
    machine_description,
    p12_window,
)
from observer.estimation import CircuitEstimate, estimate_armature, estimate_field, kernels
from observer.estimation.pso import SCHEDULES

PARAMETERS = ("Rf", "Lf", "Ra", "La", "K")
BLOCKS = ("swarm", "full")
BLOCK_TITLES = {"swarm": "swarm alone", "full": "full estimator"}
#: Relative excess cost below this is drawn at this value (log scale).
EXCESS_FLOOR = 1e-15


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.paper_table",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--seeds", type=int, default=5, help="seeds (recordings and swarms)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed")
    parser.add_argument(
        "--noise", type=float, default=0.002, help="sensor noise, fraction of rated, all channels"
    )
    parser.add_argument(
        "--convergence-iterations",
        type=int,
        default=300,
        help="iterations of the convergence runs (s-k / k-s finish their transition at 140)",
    )
    parser.add_argument(
        "--max-iterations",
        type=int,
        default=None,
        help="cap every column's iterations (for a quick look; the table says so)",
    )
    parser.add_argument("--table", type=Path, default=Path("docs/paper_table.md"))
    parser.add_argument("--figure", type=Path, default=Path("docs/convergence.png"))
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run: 2 seeds, at most 20 iterations everywhere",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds = min(args.seeds, 2)
        args.max_iterations = 20 if args.max_iterations is None else min(args.max_iterations, 20)
        args.convergence_iterations = min(args.convergence_iterations, 20)
    if args.seeds < 1:
        parser.error("--seeds must be >= 1")
    if args.convergence_iterations < 1:
        parser.error("--convergence-iterations must be >= 1")
    if args.max_iterations is not None and args.max_iterations < 1:
        parser.error("--max-iterations must be >= 1")
    return args


# ------------------------------------------------------------------ estimates


def _field(w: Window, particles: int, iterations: int, block: str, seed: int) -> CircuitEstimate:
    return estimate_field(
        w.vf, w.i_f, w.dt, n_particles=particles, max_iterations=iterations,
        rng=seed, polish=block == "full",
    )  # fmt: skip


def _armature(w: Window, particles: int, iterations: int, block: str, seed: int) -> CircuitEstimate:
    full = block == "full"
    return estimate_armature(
        w.va, w.ia, w.i_f, w.omega, w.dt, n_particles=particles, max_iterations=iterations,
        rng=seed, polish=full, compensate_input_noise=full,
    )  # fmt: skip


def run_table(
    windows: Sequence[Window], max_iterations: int | None, progress: tqdm
) -> tuple[dict[tuple[str, str, int], list[float]], dict[int, list[float]]]:
    """Estimates per ``(block, parameter, column)`` over windows; swarm-alone field times (s)."""
    values: dict[tuple[str, str, int], list[float]] = {}
    times: dict[int, list[float]] = {}
    for w in windows:
        for col, (_, particles, iterations) in enumerate(PAPER_COLUMNS):
            its = iterations if max_iterations is None else min(iterations, max_iterations)
            for block in BLOCKS:
                t0 = time.perf_counter()
                f = _field(w, particles, its, block, w.seed)
                if block == "swarm":
                    times.setdefault(col, []).append(time.perf_counter() - t0)
                a = _armature(w, particles, its, block, w.seed)
                got = {
                    "Rf": f.resistance_ohm,
                    "Lf": f.inductance_h,
                    "Ra": a.resistance_ohm,
                    "La": a.inductance_h,
                    "K": float(a.emf_constant_h or math.nan),
                }
                for name, value in got.items():
                    values.setdefault((block, name, col), []).append(value)
            progress.update(1)
    return values, times


def run_convergence(
    windows: Sequence[Window], iterations: int, progress: tqdm
) -> dict[tuple[str, str], np.ndarray]:
    """Relative excess best cost per iteration, ``(circuit, schedule) -> (n_seeds, its + 1)``."""
    out: dict[tuple[str, str], list[np.ndarray]] = {}
    for w in windows:
        # The window's minimum: the polished optimum (swarm runs can only match it).
        f = estimate_field(w.vf, w.i_f, w.dt, rng=w.seed)
        a = estimate_armature(w.va, w.ia, w.i_f, w.omega, w.dt, rng=w.seed,
                              compensate_input_noise=False)  # fmt: skip
        emf = kernels.emf_input(w.i_f, w.omega)
        floor = {
            "field": float(
                kernels.rl_swarm_costs(
                    np.log10([[f.resistance_ohm, f.inductance_h]]), w.vf, w.i_f, w.dt, True
                )[0]
            ),
            "armature": float(
                kernels.armature_swarm_costs(
                    np.log10([[a.resistance_ohm, a.inductance_h]]),
                    w.va,
                    emf,
                    w.ia,
                    w.dt,
                    True,
                    math.nan,
                )[0]
            ),  # fmt: skip
        }
        histories: dict[tuple[str, str], np.ndarray] = {}
        for schedule in SCHEDULES:
            hf = estimate_field(
                w.vf, w.i_f, w.dt, max_iterations=iterations, schedule=schedule,
                rng=w.seed, polish=False,
            ).pso.history  # fmt: skip
            ha = estimate_armature(
                w.va, w.ia, w.i_f, w.omega, w.dt, max_iterations=iterations, schedule=schedule,
                rng=w.seed, polish=False, compensate_input_noise=False,
            ).pso.history  # fmt: skip
            histories["field", schedule] = hf
            histories["armature", schedule] = ha
            progress.update(1)
        for circuit in ("field", "armature"):
            best = min(
                [floor[circuit]] + [h[-1] for (c, _), h in histories.items() if c == circuit]
            )
            for schedule in SCHEDULES:
                h = histories[circuit, schedule]
                excess = np.maximum((h - best) / abs(best), EXCESS_FLOOR)
                out.setdefault((circuit, schedule), []).append(excess)
    return {key: np.array(rows) for key, rows in out.items()}


# -------------------------------------------------------------------- outputs


def _cell(xs: Sequence[float]) -> str:
    arr = np.asarray(xs, dtype=float)
    med = float(np.median(arr))
    if arr.size == 1:
        return f"{med:.4g}"
    return f"{med:.4g} ({float(arr.min()):.4g}–{float(arr.max()):.4g})"


def format_table(
    values: dict[tuple[str, str, int], list[float]],
    times: dict[int, list[float]],
    truth: dict[str, float],
    args: argparse.Namespace,
    n_seeds: int,
) -> str:
    """The markdown document: the table, how it was made, and what it shows."""
    heads = []
    for option, particles, iterations in PAPER_COLUMNS:
        its = iterations if args.max_iterations is None else min(iterations, args.max_iterations)
        capped = "" if its == iterations else f" (capped to {its})"
        heads.append(f"{option}: {particles} p × {iterations} it{capped}")
    lines = [
        "# The paper's table, regenerated on simulated P-12 data",
        "",
        "Made by `python -m bench.paper_table"
        + (" --quick" if args.quick else "")
        + f" --seeds {n_seeds}` ({args.machine}).",
        "",
        f"Data: per seed, a {WINDOW_SAMPLES}-sample window ({WINDOW_SAMPLES / SAMPLE_RATE_HZ:g} s "
        f"at {SAMPLE_RATE_HZ:g} Hz) of a simulated P-12 recording (`observer.simulation.simulate`, "
        f"sensor noise {100 * args.noise:g} % of rated on every channel), starting a quarter "
        "window before the first field-voltage step (the duty cycle's field weakening, while "
        "the drive reverses the hoist), so both windings are excited. The truth is the "
        'paper\'s "given" values (Rf 185 Ω, Lf 50 H, Ra 3.5 Ω, La 0.02 H) and '
        f"K = {truth['K']:.4g} H.",
        "",
        f"Cells: median over {n_seeds} seeds (range over seeds in parentheses). Each seed has "
        "its own recording and swarm. *Swarm alone*: `polish=False` (armature also "
        "`compensate_input_noise=False`), what the PSO itself reaches, as in the paper. "
        "*Full*: the default estimator (LM polish; armature EIV compensation, which re-runs a "
        "narrow swarm of max(20, p/2) particles × max(30, it) iterations).",
        "",
        "| Parameter | Given | " + " | ".join(heads) + " |",
        "|---|---|" + "---|" * len(heads),
    ]
    for name in PARAMETERS:
        paper = PAPER_ESTIMATES.get(name)
        given = PAPER_GIVEN.get(name)
        lines.append(
            f"| {name} paper | {given:g} | " + " | ".join(f"{x:g}" for x in paper)
            if paper is not None and given is not None
            else f"| {name} paper | — | " + " | ".join("—" for _ in heads)
        )
        lines[-1] += " |"
        for block in BLOCKS:
            cells = [_cell(values[block, name, col]) for col in range(len(PAPER_COLUMNS))]
            lines.append(
                f"| {name} {BLOCK_TITLES[block]} | {truth[name]:.4g} | " + " | ".join(cells) + " |"
            )
    t_cells = [f"{1e3 * float(np.median(times[c])):.1f} ms" for c in range(len(PAPER_COLUMNS))]
    lines.append("| field estimate time, swarm alone (median) | | " + " | ".join(t_cells) + " |")
    lines += ["", *_findings(values, truth), ""]
    return "\n".join(lines)


def _findings(
    values: dict[tuple[str, str, int], list[float]], truth: dict[str, float]
) -> list[str]:
    """Worst relative error per block and parameter, over all columns and seeds."""
    out = ["Worst relative error over all columns and seeds:", ""]
    for block in BLOCKS:
        parts = []
        for name in PARAMETERS:
            errs = [
                abs(v - truth[name]) / truth[name]
                for col in range(len(PAPER_COLUMNS))
                for v in values[block, name, col]
            ]
            parts.append(f"{name} {100 * max(errs):.2f} %")
        out.append(f"- {BLOCK_TITLES[block]}: " + ", ".join(parts))
    out += ["", "Largest difference between the columns' medians (relative to the truth):", ""]
    for block in BLOCKS:
        parts = []
        for name in PARAMETERS:
            medians = [np.median(values[block, name, c]) for c in range(len(PAPER_COLUMNS))]
            parts.append(f"{name} {100 * (max(medians) - min(medians)) / truth[name]:.3g} %")
        out.append(f"- {BLOCK_TITLES[block]}: " + ", ".join(parts))
    out += [
        "",
        "Unlike the paper's swarm, which apparently had not converged after 100 iterations "
        "(Rf 332, Lf 2), this one searches only (R, L) per winding, on a log scale, in a range "
        "derived from the data, with the initial current and K solved in closed form for every "
        "particle: at 100 × 100 it already sits on the optimum, so more iterations or particles "
        "change the estimates only at rounding level. The spread over seeds is the noise's (see "
        "benchmarks.md for the Cramér–Rao comparison).",
    ]
    return out


def write_figure(path: Path, excess: dict[tuple[str, str], np.ndarray], n_seeds: int) -> None:
    """Best cost (excess over the window's minimum) against iteration, per schedule."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for ax, circuit in zip(axes, ("field", "armature"), strict=True):
        for schedule in SCHEDULES:
            rows = excess[circuit, schedule]
            ax.semilogy(np.arange(rows.shape[1]), rows.mean(axis=0), label=schedule)
        ax.set_title(f"{circuit} ({'Rf, Lf' if circuit == 'field' else 'Ra, La; K projected'})")
        ax.set_xlabel("iteration")
        ax.set_ylabel("(best cost − minimum) / minimum")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(title="schedule")
    fig.suptitle(
        "PSO convergence on simulated P-12 windows, 100 particles, w = 0.7, "
        f"mean of {n_seeds} seeds"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    args.machine = machine_description()  # the load average before this run adds its own
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    windows = [p12_window(seed, noise=args.noise) for seed in seeds]
    # Compile (or load from numba's cache) before anything is timed.
    _field(windows[0], 10, 2, "full", 0)
    _armature(windows[0], 10, 2, "full", 0)
    truth = windows[0].truth
    total = len(windows) * len(PAPER_COLUMNS) + len(windows) * len(SCHEDULES)
    with tqdm(total=total, desc="paper table", disable=args.no_progress, file=sys.stderr) as bar:
        values, times = run_table(windows, args.max_iterations, bar)
        excess = run_convergence(windows, args.convergence_iterations, bar)
    text = format_table(values, times, truth, args, len(windows))
    text += (
        f"\n![convergence]({args.figure.name})\n\n"
        f"Convergence ({args.figure.name}): the swarm's best cost per iteration for the paper's "
        "four schedules (social c1 = 0.1, c2 = 1.5; individual c1 = 1.5, c2 = 0.1; s-k and k-s "
        "move 0.01 per iteration from one to the other), 100 particles, "
        f"{args.convergence_iterations} iterations, drawn as excess over the window's minimum "
        "(the polished optimum) and averaged over seeds; "
        f"{EXCESS_FLOOR:g} means the minimum was reached to rounding.\n"
    )
    args.table.parent.mkdir(parents=True, exist_ok=True)
    args.table.write_text(text, encoding="utf-8")
    write_figure(args.figure, excess, len(windows))
    print(text)
    print(f"wrote {args.table} and {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
