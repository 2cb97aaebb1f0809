"""Detection and false-alarm rates of ``dcobserver diagnose`` (a benchmark, not a test).

For every effect at two magnitudes and N seeds, simulate a recording of the
P-12 that carries the effect, diagnose it with the full library, and count how
often the verdict names exactly that effect; on clean recordings of both
motors, count how often it names anything (false alarms). Also reported: the
fit improvement of the correct finding (rms of its channel, before -> after,
and the held-out improvement) and the relative error of the recovered magnitude.

    python bench/diagnose_rates.py --seeds 20 --workers 2 --out bench/diagnose_rates.jsonl \\
        --table docs/diagnosis_table.md

Results are appended to the JSONL file as they come (a rerun skips cases
already there), so a long run can be stopped and resumed.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import statistics
import sys
import time
from pathlib import Path
from typing import Any

#: effect -> (small magnitude, large magnitude, parameter compared with the truth)
CASES: dict[str, tuple[float, float, str]] = {
    "field_saturation": (0.01, 0.02, "saturation_per_a"),
    "thermal_drift": (0.03, 0.06, "resistance_rise_at_end"),
    "brush_drop": (0.15, 0.3, "brush_drop_v"),
    "armature_reaction": (0.0015, 0.003, "reaction_per_a"),
    "eddy_currents": (0.15, 0.3, "eddy_coupling"),
    "sensor_offset": (0.0075, 0.015, "ia_offset_a"),
    "sampling_skew": (0.5, 1.0, "current_delay_s"),
}


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    from observer.diagnosis.diagnose import diagnose
    from observer.estimation.motor import MOTORS
    from observer.simulation.simulate import simulate

    effects = {job["effect"]: job["magnitude"]} if job["effect"] else None
    rec = simulate(
        MOTORS[job["motor"]], duration_s=job["duration"], sample_rate_hz=job["rate"],
        seed=job["seed"], effects=effects,
    )  # fmt: skip
    t0 = time.perf_counter()
    diag = diagnose(rec)
    out = dict(job)
    out["seconds"] = time.perf_counter() - t0
    out["verdict"] = diag.verdict
    out["excess_ratio"] = {c: f.excess_ratio for c, f in diag.floors.items()}
    if job["effect"]:
        finding = next((f for f in diag.findings if f.effect == job["effect"]), None)
        if finding is not None:
            param = CASES[job["effect"]][2]
            phys = rec.metadata["effects"]["physical"]
            if param == "resistance_rise_at_end":
                # k and tau trade off along a ridge; their product over the record does not.
                k, tau = phys["thermal_rise_per_w"], phys["thermal_time_constant_s"]
                ctx = diag.context
                truth = k * ctx.mean_loss_w * (1 - math.exp(-ctx.duration_s / tau))
            else:
                truth = phys[param]
            out["fitted"] = {**finding.params, **finding.magnitude}[param]
            out["truth"] = truth
            out["rms_before"] = finding.rms_before
            out["rms_after"] = finding.rms_after
            out["holdout_gain"] = finding.evidence["holdout_gain"]
    return out


def jobs(seeds: int, duration: float, rate: float) -> list[dict[str, Any]]:
    out = []
    for effect, (small, large, _) in CASES.items():
        for magnitude in (small, large):
            for seed in range(seeds):
                out.append(
                    {"effect": effect, "magnitude": magnitude, "seed": 1000 + seed,
                     "motor": "p12", "duration": duration, "rate": rate}
                )  # fmt: skip
    for motor in ("p12", "traction-60v"):
        for seed in range(seeds):
            out.append(
                {"effect": None, "magnitude": 0.0, "seed": 2000 + seed, "motor": motor,
                 "duration": duration, "rate": rate}
            )  # fmt: skip
    return out


def _key(job: dict[str, Any]) -> tuple[Any, ...]:
    return (
        job["effect"],
        job["magnitude"],
        job["seed"],
        job["motor"],
        job["duration"],
        job["rate"],
    )


def table(results: list[dict[str, Any]]) -> str:
    lines = [
        "| effect | magnitude | runs | detected | other verdict (not none) | rms before -> after "
        "(median) | held-out gain (median) | magnitude error (median) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for effect, (small, large, param) in CASES.items():
        for mag in (small, large):
            rs = [r for r in results if r["effect"] == effect and r["magnitude"] == mag]
            if not rs:
                continue
            hit = sum(r["verdict"] == effect for r in rs)
            other = sum(r["verdict"] not in (effect, "none") for r in rs)
            with_fit = [r for r in rs if "rms_after" in r]
            before = statistics.median(r["rms_before"] for r in with_fit) if with_fit else math.nan
            after = statistics.median(r["rms_after"] for r in with_fit) if with_fit else math.nan
            gain = statistics.median(r["holdout_gain"] for r in with_fit) if with_fit else math.nan
            err = (
                statistics.median(abs(r["fitted"] / r["truth"] - 1) for r in with_fit)
                if with_fit
                else math.nan
            )
            lines.append(
                f"| {effect} | {mag:g} | {len(rs)} | {100 * hit / len(rs):.0f} % | "
                f"{other} | {before:.4g} -> {after:.4g} A | {100 * gain:.1f} % | "
                f"{100 * err:.1f} % ({param}) |"
            )
    for motor in ("p12", "traction-60v"):
        rs = [r for r in results if r["effect"] is None and r["motor"] == motor]
        if rs:
            alarms = [r["verdict"] for r in rs if r["verdict"] != "none"]
            lines.append(
                f"| clean ({motor}) | - | {len(rs)} | false alarms: "
                f"{100 * len(alarms) / len(rs):.0f} % {sorted(set(alarms)) or ''} | | | | |"
            )
    secs = [r["seconds"] for r in results]
    if secs:
        lines.append("")
        lines.append(
            f"{len(results)} diagnoses, median {statistics.median(secs):.1f} s each "
            f"({results[0]['duration']:g} s recordings at {results[0]['rate']:g} Hz)."
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=2000.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("bench/diagnose_rates.jsonl"))
    parser.add_argument("--table", type=Path, default=None, help="write the markdown table here")
    parser.add_argument("--effects", default=None, help="comma-separated subset of effects")
    args = parser.parse_args(argv)

    todo = jobs(args.seeds, args.duration, args.rate)
    if args.effects:
        keep = set(args.effects.split(","))
        todo = [j for j in todo if j["effect"] is None or j["effect"] in keep]
    done: list[dict[str, Any]] = []
    if args.out.exists():
        done = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
    seen = {_key(r) for r in done}
    todo = [j for j in todo if _key(j) not in seen]
    # Interleave so that a partial run covers every effect.
    todo.sort(key=lambda j: (j["seed"] % 1000, str(j["effect"]), j["magnitude"], j["motor"]))
    print(f"{len(done)} done, {len(todo)} to run", file=sys.stderr)
    ctx = multiprocessing.get_context("spawn")  # numba's OpenMP layer does not survive fork
    with ctx.Pool(args.workers) as pool, args.out.open("a") as sink:
        for i, result in enumerate(pool.imap_unordered(run_case, todo), 1):
            sink.write(json.dumps(result) + "\n")
            sink.flush()
            done.append(result)
            print(
                f"[{i}/{len(todo)}] {result['effect']} {result['magnitude']} seed "
                f"{result['seed']} {result['motor']}: {result['verdict']} "
                f"({result['seconds']:.1f} s)",
                file=sys.stderr,
            )
    text = table(done)
    print(text)
    if args.table:
        args.table.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
