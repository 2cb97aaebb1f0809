"""Accuracy of the whole-recording estimator on converter-fed recordings (a benchmark, not a test).

For every motor, front end, sample rate, converter and seed: simulate a healthy motor for 30 s
behind a real drive and a measurement chain (a 12-bit ADC and 0.2 % sensor noise on every
channel, the front end's anti-aliasing filters: ``--front-ends``, :data:`FRONT_ENDS`; by
default the ``realistic`` preset's 2nd-order Butterworth at fs/4), estimate both windings with
the API ``dcobserver estimate`` uses (:func:`observer.estimation.estimate_recording`), giving
it the chain the recording was made through (:meth:`~observer.simulation.chain.MeasurementChain.
to_config`, the ``[chain]`` a user would configure) or, for the ``-untold`` front ends, nothing,
and compare with the truth. The table gives, per case and parameter, the median and the largest
|error| in percent, the median |error / std| (an honest std gives about 0.67) and in how many
recordings the estimator said its model does not describe the circuit (``describes_window``
false: the values are then not to be used).

Drives: ``thyristor`` is the dual 6-pulse bridge on 50 Hz with the single-phase field bridge
(the ``realistic`` preset), ``chopper`` the 4-quadrant H-bridge at 2 kHz with a field chopper.

``--variants`` changes the drive or the chain beyond the named front ends, to check the
estimator on chains it was not tuned on (:data:`VARIANTS`: 60 Hz mains, commutation overlap,
other filter families and orders, a multiplexed ADC's skew, a 16-bit ADC).

    python -m bench.accuracy_rates --seeds 20 --out bench/accuracy_rates.jsonl   # the full run
    python -m bench.accuracy_rates --seeds 2                                     # a smoke run
    python -m bench.accuracy_rates --front-ends none,mixed,mixed-untold --motors p12,industrial-440v
    python -m bench.accuracy_rates --drives thyristor --front-ends butter2-untold \
        --variants 60hz,overlap,bessel4,butter4-v,skew,16bit --motors p12,industrial-440v

Results are appended to ``--out`` (JSON lines) as they come; a rerun skips the cases already
there, so a long run can be stopped and resumed.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing
import statistics
import sys
import time
from pathlib import Path
from typing import Any

#: Drive name -> (armature converter, field converter).
DRIVES: dict[str, tuple[str, str]] = {
    "thyristor": ("thyristor-6p", "bridge-1p"),
    "chopper": ("chopper", "chopper"),
}
#: Parameter -> (circuit, key in CircuitEstimate.to_dict(), motor field).
PARAMETERS: dict[str, tuple[str, str, str]] = {
    "Rf": ("field", "R", "field_resistance_ohm"),
    "Lf": ("field", "L", "field_inductance_h"),
    "Ra": ("armature", "R", "armature_resistance_ohm"),
    "La": ("armature", "L", "armature_inductance_h"),
    "K": ("armature", "K", "emf_constant_h"),
}


#: Front end -> (filter per channel, whether the estimator is told the chain). ``va``/``vf``
#: take the first filter, the currents and the speed the second.
FRONT_ENDS: dict[str, tuple[str, str, bool]] = {
    "butter2": ("butter2@fs/4", "butter2@fs/4", True),
    "butter2-untold": ("butter2@fs/4", "butter2@fs/4", False),
    "none": ("none", "none", True),
    "mixed": ("rc1@fs/4", "butter2@fs/4", True),
    "mixed-untold": ("rc1@fs/4", "butter2@fs/4", False),
    "bare-v": ("none", "butter2@fs/4", True),
    "bare-v-untold": ("none", "butter2@fs/4", False),
}


def _mains_60hz(drive: Any, rate: float) -> Any:
    return drive.replace(converter=dataclasses.replace(drive.converter, mains_hz=60.0))


def _overlap(drive: Any, rate: float) -> Any:
    return drive.replace(converter=dataclasses.replace(drive.converter, source_inductance_h=2e-4))


def _filters(voltage: str, current: str) -> Any:
    def change(drive: Any, rate: float) -> Any:
        from observer.config import parse_filter
        from observer.simulation.chain import CHANNELS, apply_per_channel

        changes = {ch: parse_filter(voltage if ch in ("va", "vf") else current) for ch in CHANNELS}
        return drive.replace(chain=apply_per_channel(drive.chain, changes))

    return change


def _skew(drive: Any, rate: float) -> Any:
    from observer.simulation.chain import apply_per_channel

    # one ADC multiplexed over the channels: each sampled a quarter period after the last
    delays = {"ia": 0.25, "if": 0.5, "omega": 0.75}
    changes = {ch: {"delay_s": share / rate} for ch, share in delays.items()}
    return drive.replace(chain=apply_per_channel(drive.chain, changes))


def _adc_bits(bits: int) -> Any:
    def change(drive: Any, rate: float) -> Any:
        from observer.simulation.chain import apply_per_channel

        return drive.replace(chain=apply_per_channel(drive.chain, {"*": {"bits": bits}}))

    return change


#: Variant -> (what it changes, ``f(drive, sample_rate_hz) -> drive``), applied after the front
#: end (a variant that sets filters replaces its filters). ``standard``: nothing.
VARIANTS: dict[str, tuple[str, Any]] = {
    "standard": ("as the front end says", lambda drive, rate: drive),
    "60hz": ("60 Hz mains", _mains_60hz),
    "overlap": ("commutation overlap, 0.2 mH per phase", _overlap),
    "bessel4": ("4th-order Bessel at fs/5 on every channel",
                _filters("bessel4@fs/5", "bessel4@fs/5")),
    "butter4-v": ("4th-order Butterworth at fs/3 on the voltages, 2nd at fs/4 on the rest",
                  _filters("butter4@fs/3", "butter2@fs/4")),
    "skew": ("one multiplexed ADC: ia, if, omega 1/4, 1/2, 3/4 of a period after the voltages",
             _skew),
    "16bit": ("16-bit ADC on every channel", _adc_bits(16)),
}  # fmt: skip


def variant_of(job: dict[str, Any]) -> str:
    """A case's variant (rows written before there were several: ``standard``)."""
    return str(job.get("variant", "standard"))


def front_end_of(job: dict[str, Any]) -> str:
    """A case's front end (rows written before there were several: ``butter2``)."""
    return str(job.get("front_end", "butter2"))


#: The chopper's PWM carrier (Hz) where a case does not name one: the simulator's default.
DEFAULT_CARRIER_HZ = 2000.0


def carrier_of(job: dict[str, Any]) -> float | None:
    """A chopper case's carrier (Hz; rows written before there were several: the default);
    None for other drives."""
    if job["drive"] != "chopper":
        return None
    return float(job.get("carrier_hz") or DEFAULT_CARRIER_HZ)


def drive_label(job: dict[str, Any]) -> str:
    """The drive's name in the table, with a chopper's carrier where it is not the default."""
    carrier = carrier_of(job)
    label = str(job["drive"])
    if carrier is not None and carrier != DEFAULT_CARRIER_HZ:
        label += f" {carrier / 1000:g} kHz carrier"
    variant = variant_of(job)
    return label if variant == "standard" else f"{label}, {variant}"


def front_end_drive(drive: Any, front_end: str) -> Any:
    """``drive`` with front end ``front_end`` (:data:`FRONT_ENDS`) on its channels."""
    from observer.config import parse_filter
    from observer.simulation.chain import CHANNELS, apply_per_channel

    voltage, current = FRONT_ENDS[front_end][:2]
    changes = {ch: parse_filter(voltage if ch in ("va", "vf") else current) for ch in CHANNELS}
    return drive.replace(chain=apply_per_channel(drive.chain, changes))


def drive_spec(name: str) -> Any:
    """The :class:`~observer.simulation.converter.DriveSpec` of drive ``name``: its converters
    behind the ``realistic`` preset's measurement chain."""
    from observer.simulation.converter import PRESETS, ConverterSpec

    realistic = PRESETS["realistic"]
    assert realistic is not None
    armature, field = DRIVES[name]
    return realistic.replace(converter=ConverterSpec(armature=armature, field=field))


def run_case(job: dict[str, Any]) -> dict[str, Any]:
    """Simulate and estimate one case; the result row (errors, stds, timings)."""
    from observer.estimation import estimate_recording
    from observer.estimation.motor import MOTORS
    from observer.simulation.simulate import simulate

    motor = MOTORS[job["motor"]]
    front_end = front_end_of(job)
    drive = front_end_drive(drive_spec(job["drive"]), front_end)
    carrier = carrier_of(job)
    if carrier is not None and carrier != DEFAULT_CARRIER_HZ:
        drive = drive.replace(converter=dataclasses.replace(drive.converter, switching_hz=carrier))
    drive = VARIANTS[variant_of(job)][1](drive, float(job["rate"]))
    t0 = time.perf_counter()
    rec = simulate(
        motor, duration_s=job["duration"], sample_rate_hz=job["rate"], noise=job["noise"],
        seed=job["seed"], drive=drive, drive_name=job["drive"],
    )  # fmt: skip
    t1 = time.perf_counter()
    told = FRONT_ENDS[front_end][2]
    results = estimate_recording(rec, chain=drive.chain.to_config() if told else None)
    t2 = time.perf_counter()
    out = dict(job)
    if carrier is not None:
        out["carrier_hz"] = float(rec.metadata["converter"]["armature"]["switching_hz"])
    out["simulate_s"], out["estimate_s"] = t1 - t0, t2 - t1
    est = {circuit: r.to_dict() for circuit, r in results.items()}
    for name, (circuit, key, field) in PARAMETERS.items():
        true = float(getattr(motor, field))
        value = float(est[circuit][key])
        std = float(est[circuit]["std"].get(key, math.nan))
        out[name] = {
            "true": true, "estimate": value, "std": std,
            "error_pct": 100.0 * (value - true) / true,
            "z": (value - true) / std if std > 0 else math.inf,
        }  # fmt: skip
    for circuit in ("field", "armature"):
        out[f"{circuit}_describes"] = bool(est[circuit]["describes_window"])
        out[f"{circuit}_intersample"] = est[circuit]["intersample"]
    return out


def jobs(args: argparse.Namespace) -> list[dict[str, Any]]:
    return [
        {
            "motor": motor,
            "rate": rate,
            "drive": drive,
            "front_end": front_end,
            "seed": seed,
            "duration": args.duration,
            "noise": args.noise,
            **({"carrier_hz": carrier} if carrier is not None else {}),
            **({"variant": variant} if variant != "standard" else {}),
        }  # fmt: skip
        for motor in args.motors
        for front_end in args.front_ends
        for rate in args.rates
        for drive in args.drives
        for carrier in (args.carriers if drive == "chopper" else [None])
        for variant in getattr(args, "variants", ["standard"])
        for seed in range(args.seeds)
    ]


def _key(job: dict[str, Any]) -> tuple[Any, ...]:
    return (
        job["motor"], front_end_of(job), job["rate"], job["drive"], carrier_of(job),
        variant_of(job), job["seed"], job["duration"], job["noise"],
    )  # fmt: skip


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown: per rate, drive and parameter, median and max |error| % and median |z|."""
    lines = [
        "| motor | front end | rate | drive | param | seeds | median abs error | max abs error "
        "| median abs(error/std) | not described |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]

    def case(r: dict[str, Any]) -> tuple[Any, ...]:
        return (r["motor"], front_end_of(r), r["rate"], drive_label(r))

    for motor, front_end, rate, drive in sorted({case(r) for r in rows}):
        cell = [r for r in rows if case(r) == (motor, front_end, rate, drive)]
        for name in PARAMETERS:
            errors = [abs(r[name]["error_pct"]) for r in cell]
            z = [abs(r[name]["z"]) for r in cell]
            circuit = PARAMETERS[name][0]
            held = sum(not r[f"{circuit}_describes"] for r in cell)
            lines.append(
                f"| {motor} | {front_end} | {rate / 1000:g} kHz | {drive} | {name} | {len(cell)} | "
                f"{statistics.median(errors):.2f} % | {max(errors):.2f} % | "
                f"{statistics.median(z):.2f} | {held} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from observer.estimation.motor import MOTORS

    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0] if __doc__ else None,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--seeds", type=int, default=20, help="recordings per rate and drive")
    parser.add_argument(
        "--rates", type=lambda s: [float(x) for x in s.split(",")], default="2000,5000,10000",
        metavar="HZ,...", help="sample rates (Hz)",
    )  # fmt: skip
    parser.add_argument(
        "--drives", type=lambda s: s.split(","), default=",".join(DRIVES), metavar="NAME,...",
        help=f"drives: {', '.join(DRIVES)}",
    )  # fmt: skip
    parser.add_argument(
        "--motors",
        type=lambda s: s.split(","),
        default="p12",
        metavar="NAME,...",
        help=f"motors: {', '.join(sorted(MOTORS))}",
    )
    parser.add_argument(
        "--front-ends", type=lambda s: s.split(","), default="butter2", metavar="NAME,...",
        help="front ends (voltage / current filters, told to the estimator or not): " + "; ".join(
            f"{k}: {v} / {i}{'' if t else ', untold'}" for k, (v, i, t) in FRONT_ENDS.items()
        ),
    )  # fmt: skip
    parser.add_argument(
        "--carriers", type=lambda s: [float(x) for x in s.split(",")],
        default=str(DEFAULT_CARRIER_HZ), metavar="HZ,...",
        help="the chopper's PWM carriers (Hz; its pulses at twice each)",
    )  # fmt: skip
    parser.add_argument(
        "--variants", type=lambda s: s.split(","), default="standard", metavar="NAME,...",
        help="changes of the drive or chain beyond the front end: " + "; ".join(
            f"{k}: {what}" for k, (what, _) in VARIANTS.items()
        ),
    )  # fmt: skip
    parser.add_argument("--duration", type=float, default=30.0, metavar="S", help="length (s)")
    parser.add_argument("--noise", type=float, default=0.002, metavar="FRACTION",
                        help="sensor noise, fraction of each channel's rated value")  # fmt: skip
    parser.add_argument("--workers", type=int, default=1, help="processes")
    parser.add_argument(
        "--out", type=Path, default=None, metavar="FILE.jsonl",
        help="append each case's result here; a rerun skips what is there",
    )  # fmt: skip
    parser.add_argument("--table", type=Path, default=None, metavar="FILE.md",
                        help="also write the table here")  # fmt: skip
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    unknown = [d for d in args.drives if d not in DRIVES]
    unknown += [f for f in args.front_ends if f not in FRONT_ENDS]
    unknown += [m for m in args.motors if m not in MOTORS]
    unknown += [v for v in args.variants if v not in VARIANTS]
    if unknown or args.seeds < 1 or args.workers < 1 or not all(r > 0 for r in args.rates):
        parser.error(
            f"--drives from {', '.join(DRIVES)}, --front-ends from {', '.join(FRONT_ENDS)}, "
            f"--variants from {', '.join(VARIANTS)}, "
            f"--motors from {', '.join(sorted(MOTORS))}; --seeds, --workers, --rates > 0"
        )

    from tqdm import tqdm

    from bench.common import machine_description

    todo = jobs(args)
    rows: list[dict[str, Any]] = []
    if args.out is not None and args.out.exists():
        wanted = {_key(j) for j in todo}
        for line in args.out.read_text().splitlines():
            row = json.loads(line)
            if _key(row) in wanted:
                rows.append(row)
        done = {_key(r) for r in rows}
        todo = [j for j in todo if _key(j) not in done]
    machine = machine_description()  # its load average is the start's
    started = time.perf_counter()
    with tqdm(total=len(todo), desc="cases", disable=args.no_progress, file=sys.stderr) as bar:
        pool = multiprocessing.Pool(args.workers) if args.workers > 1 else None
        try:
            results = pool.imap_unordered(run_case, todo) if pool else map(run_case, todo)
            for row in results:
                rows.append(row)
                if args.out is not None:
                    with args.out.open("a") as fh:
                        fh.write(json.dumps(row) + "\n")
                bar.update()
        finally:
            if pool is not None:
                pool.terminate()
                pool.join()
    text = (
        f"{args.duration:g} s per recording, noise {args.noise:g} of rated, 12-bit ADC on "
        "every channel, front ends as named (--help); "
        f"{time.perf_counter() - started:.0f} s for {len(todo)} new cases on "
        f"{machine}\n\n{table(rows)}"
    )
    print(text)
    if args.table is not None:
        args.table.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
