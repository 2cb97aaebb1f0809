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

``--drive realistic`` runs the converter-fed cases instead (issue 10, section 4): every
recording is made behind the dual 6-pulse thyristor bridge and the single-phase field bridge
(the ``realistic`` preset: 2nd-order Butterworth at fs/4 and a 12-bit ADC on every channel),
at each of ``--rates``:

- ``clean``: a healthy motor (P-12 and the industrial 440 V one), diagnosed without and with
  the chain configured (``[chain]`` as :meth:`MeasurementChain.to_config` gives it); right is
  ``none`` (a measurement-chain finding beside it is allowed, a motor effect is not);
- ``effect``: brush drop 1 V, a thermal rise (8 % at rated loss in steady state, time
  constant 20 s: about 2 % over a 6 s recording; the rise at the end is recorded), a 1 %
  current-sensor offset on the P-12; right is the effect's name;
- ``chain``: no anti-aliasing filter, a first-order voltage front end beside the second-order
  current one, the current channels sampled 20 us late; right is a measurement-chain finding
  and no motor effect;
- ``outside``: a back-EMF ripple at 8x shaft speed and a load-dependent speed-sensor error,
  effects the library does not have; right is ``unexplained``.

    python bench/diagnose_rates.py --drive realistic --seeds 5 --workers 1 \
        --out bench/diagnose_converter.jsonl --table OUT.md

``--converter chopper`` (with ``--drive realistic``) runs the same cases behind the 4-quadrant
chopper and a field chopper (2 kHz carrier) instead of the bridges:

    python bench/diagnose_rates.py --drive realistic --converter chopper --seeds 4 \
        --duration 10 --out bench/diagnose_chopper.jsonl --table OUT.md

``--variants`` (with ``--drive realistic``) runs the cases again on chains nothing was tuned on
(:data:`bench.accuracy_rates.VARIANTS`: 60 Hz mains, commutation overlap, 4th-order Bessel
filters, 4th-order voltage filters beside 2nd-order currents, a multiplexed ADC, 16 bits).
Where a variant sets the channels apart (:data:`APART`) and the chain is not configured, a
healthy motor's right answer is the chain's (a chain finding, no motor effect):

    python bench/diagnose_rates.py --drive realistic --seeds 1 --workers 2 --cases \
        "clean p12;clean industrial-440v;brush_drop 1 V;thermal_drift ~2 % rise;sensor_offset 1 %" \
        --variants 60hz,overlap,bessel4,butter4-v,16bit,skew --out bench/diagnose_variants.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import statistics
import sys
import time
from collections.abc import Sequence
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
    from observer.diagnosis.effects import thermal_rise
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
                truth = thermal_rise(k, tau, ctx.mean_loss_w, ctx.duration_s)
            else:
                truth = phys[param]
            out["fitted"] = {**finding.params, **finding.magnitude}[param]
            out["truth"] = truth
            out["rms_before"] = finding.rms_before
            out["rms_after"] = finding.rms_after
            out["holdout_gain"] = finding.evidence["holdout_gain"]
    return out


#: Converter-fed cases: name -> (kind, motor, effects, chain variant).
CONVERTER_CASES: dict[str, tuple[str, str, dict[str, float] | None, str]] = {
    "clean p12": ("clean", "p12", None, "realistic"),
    "clean industrial-440v": ("clean", "industrial-440v", None, "realistic"),
    "brush_drop 1 V": ("effect", "p12", {"brush_drop": 1.0}, "realistic"),
    # 8 % at rated loss in steady state (tau 20 s): about a 2 % rise over a 6 s recording.
    "thermal_drift ~2 % rise": ("effect", "p12", {"thermal_drift": 0.08}, "realistic"),
    "sensor_offset 1 %": ("effect", "p12", {"sensor_offset": 0.01}, "realistic"),
    "no anti-aliasing filter": ("chain", "p12", None, "no_filter"),
    "va, vf rc1 beside ia, if butter2": ("chain", "p12", None, "mismatched"),
    "ia, if sampled 20 us late": ("chain", "p12", None, "skew"),
    "emf_ripple 2 % (8x shaft)": ("outside", "p12", {"emf_ripple": 0.02}, "realistic"),
    "tacho_error 1 %": ("outside", "p12", {"tacho_error": 0.01}, "realistic"),
}


#: Variants (:data:`bench.accuracy_rates.VARIANTS`) that set the voltage and current channels
#: apart: a healthy motor is right with a chain finding and no motor effect.
APART = ("butter4-v", "skew")


def converter_drive(variant: str) -> Any:
    """The realistic preset's drive with the measurement chain of ``variant``."""
    from observer.simulation.chain import ChannelChain, MeasurementChain
    from observer.simulation.converter import PRESETS

    realistic = PRESETS["realistic"]
    assert realistic is not None
    chain = realistic.chain
    if variant == "no_filter":
        chain = MeasurementChain.uniform(ChannelChain(bits=12))
    elif variant == "mismatched":
        for ch in ("va", "vf"):
            chain = chain.with_channel(ch, filter="rc", order=1, cutoff_per_fs=0.25)
    elif variant == "skew":
        for ch in ("ia", "if"):
            chain = chain.with_channel(ch, delay_s=20e-6)
    return realistic.replace(chain=chain)


def run_converter_case(job: dict[str, Any]) -> dict[str, Any]:
    from bench.accuracy_rates import VARIANTS
    from observer.diagnosis.diagnose import diagnose
    from observer.diagnosis.effects import thermal_rise
    from observer.estimation.motor import MOTORS
    from observer.estimation.ranges import EstimationError
    from observer.simulation.simulate import simulate

    kind, motor, effects, variant = CONVERTER_CASES[job["case"]]
    other = job.get("drive_variant", "standard")
    drive = VARIANTS[other][1](converter_drive(variant), float(job["rate"]))
    if job.get("converter") == "chopper":
        drive = drive.replace(
            converter=drive.converter.replace(armature="chopper", field="chopper")
        )
    if kind == "clean" and other in APART and not job["configured"]:
        kind = "chain"  # told, the chain is modelled and nothing is left to report
    rec = simulate(
        MOTORS[motor], duration_s=job["duration"], sample_rate_hz=job["rate"],
        seed=job["seed"], effects=effects, drive=drive, drive_name="realistic",
    )  # fmt: skip
    chain = drive.chain.to_config() if job["configured"] else None
    t0 = time.perf_counter()
    out = dict(job)
    try:
        diag = diagnose(rec, chain=chain)
    except EstimationError as exc:
        # What `dcobserver diagnose` says instead of a verdict (a wrong answer in the table).
        out.update(seconds=time.perf_counter() - t0, verdict="error", description=str(exc),
                   chain=[], right=False)  # fmt: skip
        return out
    out["seconds"] = time.perf_counter() - t0
    out["verdict"] = diag.verdict
    out["description"] = diag.description
    out["chain"] = sorted({c.kind for c in diag.chain})
    if kind == "effect":
        assert effects is not None
        out["right"] = diag.verdict == next(iter(effects))
        if "thermal_drift" in effects:
            phys = rec.metadata["effects"]["physical"]
            tau = phys["thermal_time_constant_s"]
            ctx = diag.context
            out["rise_at_end"] = thermal_rise(
                phys["thermal_rise_per_w"], tau, ctx.mean_loss_w, ctx.duration_s
            )
    elif kind == "clean":
        out["right"] = diag.verdict == "none"
    elif kind == "chain":
        out["right"] = bool(diag.chain) and diag.verdict in ("none", "unexplained")
    else:
        out["right"] = diag.verdict == "unexplained"
    return out


def converter_jobs(
    seeds: int,
    duration: float,
    rates: list[float],
    cases: list[str] | None = None,
    variants: Sequence[str] = ("standard",),
    converter: str = "thyristor",
) -> list[dict[str, Any]]:
    out = []
    for name, (kind, _, _, _) in CONVERTER_CASES.items():
        if cases and name not in cases:
            continue
        for variant in variants:
            for rate in rates:
                for configured in (False, True) if kind == "clean" else (False,):
                    for seed in range(seeds):
                        out.append(
                            {"case": name, "rate": rate, "configured": configured,
                             "seed": 3000 + seed, "duration": duration,
                             **({"drive_variant": variant} if variant != "standard" else {}),
                             **({"converter": converter} if converter != "thyristor" else {})}
                        )  # fmt: skip
    return out


def converter_table(results: list[dict[str, Any]]) -> str:
    rates = sorted({r["rate"] for r in results})
    head = " | ".join(f"{r / 1000:g} kHz" for r in rates)
    lines = [
        f"| case | right is | chain configured | {head} | wrong verdicts |",
        "|---|---|---|" + "---|" * len(rates) + "---|",
    ]
    right_is = {
        "clean": "`none`",
        "effect": "the effect",
        "chain": "a chain finding, no motor effect",
        "outside": "`unexplained`",
    }
    variants = sorted({_variant(r) for r in results}, key=lambda v: (v != "standard", v))
    for name, (case_kind, *_rest) in CONVERTER_CASES.items():
        for variant, configured in ((v, c) for v in variants for c in (False, True)):
            rs = [
                r
                for r in results
                if r["case"] == name and r["configured"] == configured and _variant(r) == variant
            ]
            if not rs:
                continue
            apart = case_kind == "clean" and variant in APART and not configured
            kind = "chain" if apart else case_kind
            label = name if variant == "standard" else f"{name}, {variant}"
            if any(r.get("converter") == "chopper" for r in rs):
                label += ", chopper"
            cells = []
            for rate in rates:
                at = [r for r in rs if r["rate"] == rate]
                ok = sum(r["right"] for r in at)
                cells.append(f"{ok}/{len(at)}" if at else "-")
            wrong = sorted({r["verdict"] for r in rs if not r["right"]})
            lines.append(
                f"| {label} | {right_is[kind]} | {'yes' if configured else 'no'} | "
                + " | ".join(cells)
                + f" | {', '.join(wrong)} |"
            )
    return "\n".join(lines + _timing(results, ""))


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
    return "\n".join(lines + _timing(results, f" at {results[0]['rate']:g} Hz" if results else ""))


def _timing(results: list[dict[str, Any]], where: str) -> list[str]:
    """The table's last lines: how many diagnoses, how long each took."""
    secs = [r["seconds"] for r in results]
    if not secs:
        return []
    return [
        "",
        f"{len(results)} diagnoses, median {statistics.median(secs):.1f} s each "
        f"({results[0]['duration']:g} s recordings{where}).",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--duration", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=2000.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--out", type=Path, default=None,
        help="JSON lines of results (default: bench/diagnose_rates.jsonl, with --drive "
        "realistic bench/diagnose_converter.jsonl)",
    )  # fmt: skip
    parser.add_argument("--table", type=Path, default=None, help="write the markdown table here")
    parser.add_argument("--effects", default=None, help="comma-separated subset of effects")
    parser.add_argument(
        "--drive", choices=("ideal", "realistic"), default="ideal",
        help="ideal: the effect and clean cases above; realistic: the converter-fed cases",
    )  # fmt: skip
    parser.add_argument(
        "--rates", default="2000,5000,10000", help="sample rates (Hz) of --drive realistic"
    )
    parser.add_argument(
        "--cases", default=None, help="';'-separated subset of the converter-fed case names"
    )
    parser.add_argument(
        "--converter", choices=("thyristor", "chopper"), default="thyristor",
        help="with --drive realistic: the drive behind which the cases run (chopper: the "
        "4-quadrant chopper and a field chopper, 2 kHz carrier)",
    )  # fmt: skip
    parser.add_argument(
        "--variants", default="standard",
        help="with --drive realistic: chains beyond the cases' own (bench.accuracy_rates "
        "--variants), comma-separated",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if args.out is None:
        args.out = Path(
            "bench/diagnose_converter.jsonl"
            if args.drive == "realistic"
            else "bench/diagnose_rates.jsonl"
        )
    if args.drive == "realistic":
        return converter_main(args)

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
    _run(args, todo, done, run_case, _describe_case, table)
    return 0


def _describe_case(result: dict[str, Any]) -> str:
    return (
        f"{result['effect']} {result['magnitude']} seed {result['seed']} {result['motor']}: "
        f"{result['verdict']}"
    )


def _describe_converter_case(result: dict[str, Any]) -> str:
    variant = _variant(result)
    return (
        f"{result['case']}{'' if variant == 'standard' else ', ' + variant} {result['rate']:g} Hz "
        f"{'configured ' if result['configured'] else ''}seed {result['seed']}: "
        f"{result['verdict']} {result['chain']} {'right' if result['right'] else 'WRONG'}"
    )


def _run(
    args: argparse.Namespace,
    todo: list[dict[str, Any]],
    done: list[dict[str, Any]],
    worker: Any,
    describe: Any,
    make_table: Any,
) -> None:
    """Run ``todo`` on ``args.workers`` processes, append to ``args.out``, print the table."""
    print(f"{len(done)} done, {len(todo)} to run", file=sys.stderr)
    ctx = multiprocessing.get_context("spawn")  # numba's OpenMP layer does not survive fork
    with ctx.Pool(args.workers) as pool, args.out.open("a") as sink:
        for i, result in enumerate(pool.imap_unordered(worker, todo), 1):
            sink.write(json.dumps(result) + "\n")
            sink.flush()
            done.append(result)
            print(
                f"[{i}/{len(todo)}] {describe(result)} ({result['seconds']:.1f} s)",
                file=sys.stderr,
            )
    text = make_table(done)
    print(text)
    if args.table:
        args.table.write_text(text + "\n")


def _variant(row: dict[str, Any]) -> str:
    return str(row.get("drive_variant", "standard"))


def converter_main(args: argparse.Namespace) -> int:
    from bench.accuracy_rates import VARIANTS

    rates = [float(r) for r in args.rates.split(",")]
    cases = args.cases.split(";") if args.cases else None
    variants = args.variants.split(",")
    unknown = [c for c in cases or () if c not in CONVERTER_CASES]
    unknown += [v for v in variants if v not in VARIANTS]
    if unknown:
        print(
            f"diagnose_rates: unknown {', '.join(unknown)}; cases: {'; '.join(CONVERTER_CASES)}; "
            f"variants: {', '.join(VARIANTS)}",
            file=sys.stderr,
        )
        return 2
    todo = converter_jobs(args.seeds, args.duration, rates, cases, variants, args.converter)
    keys = ("case", "rate", "configured", "seed", "duration")

    def key(row: dict[str, Any]) -> tuple[Any, ...]:
        return (*(row[k] for k in keys), _variant(row), row.get("converter", "thyristor"))

    done: list[dict[str, Any]] = []
    if args.out.exists():
        done = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
    seen = {key(r) for r in done}
    todo = [j for j in todo if key(j) not in seen]
    # Seed by seed, so that a partial run covers every case and rate.
    todo.sort(key=lambda j: (j["seed"], j["rate"]))
    _run(args, todo, done, run_converter_case, _describe_converter_case, converter_table)
    return 0


if __name__ == "__main__":
    # Run as a script (``python bench/diagnose_rates.py``): the variants live in bench/.
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    sys.exit(main())
