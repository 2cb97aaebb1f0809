"""``dcobserver estimate``: estimate the winding parameters of a recording."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping
from typing import Any


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="REC", help="recording: .csv, .csv.gz or .mcap")
    parser.add_argument(
        "--circuit", choices=("both", "field", "armature"), default="both",
        help="which winding to estimate",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--config", metavar="TOML", help="config file narrowing the search")
    parser.add_argument("--particles", type=int, default=None, help="swarm size [100]")
    parser.add_argument("--iterations", type=int, default=None, help="swarm iterations [100]")
    parser.add_argument(
        "--schedule", default=None, choices=("s-k", "k-s", "social", "individual"),
        help="PSO coefficient schedule [s-k]",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=None, help="seed of the swarm [0]")
    parser.add_argument(
        "--no-polish", action="store_true",
        help="report the swarm's best as is (no Levenberg-Marquardt refinement)",
    )  # fmt: skip


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.config import EstimateConfig, load_config
    from observer.estimation import estimate_recording
    from observer.recording import read_recording

    config = load_config(args.config) if args.config else None
    settings = config.estimate if config is not None else EstimateConfig()
    overrides = {
        "particles": args.particles,
        "iterations": args.iterations,
        "schedule": args.schedule,
        "seed": args.seed,
    }
    settings = settings.replace(**{k: v for k, v in overrides.items() if v is not None})
    if args.no_polish:
        settings = settings.replace(polish=False)
    if settings.particles < 2 or settings.iterations < 1:
        raise UserError("--particles must be >= 2 and --iterations >= 1")
    rec = read_recording(args.recording)
    circuits = ("field", "armature") if args.circuit == "both" else (args.circuit,)
    chain = config.chain if config is not None else None
    results = estimate_recording(rec, circuits, settings, path=args.recording, chain=chain)
    report: dict[str, Any] = {name: est.to_dict() for name, est in results.items()}
    truth = rec.metadata.get("motor")
    if args.json:
        json.dump(report, sys.stdout, indent=None, default=_json_default)
        sys.stdout.write("\n")
    else:
        print(_table(report, dict(truth) if isinstance(truth, Mapping) else None))
    return 0


def _json_default(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


_TRUTH_KEYS = {
    ("field", "R"): "field_resistance_ohm",
    ("field", "L"): "field_inductance_h",
    ("armature", "R"): "armature_resistance_ohm",
    ("armature", "L"): "armature_inductance_h",
    ("armature", "K"): "emf_constant_h",
}
_UNITS = {"R": "ohm", "L": "H", "K": "H"}


def _table(report: dict[str, Any], truth: dict[str, Any] | None) -> str:
    lines = []
    header = f"{'circuit':<9} {'param':<5} {'estimate':>12} {'+-1 sigma':>11} {'unit':<4}"
    if truth:
        header += f" {'true':>12} {'error':>8}"
    lines.append(header)
    for circuit, values in report.items():
        for name in ("R", "L", "K"):
            if name not in values:
                continue
            row = (
                f"{circuit:<9} {name:<5} {values[name]:>12.6g} "
                f"{values['std'].get(name, float('nan')):>11.3g} {_UNITS[name]:<4}"
            )
            key = _TRUTH_KEYS.get((circuit, name))
            if truth and key in truth:
                true = float(truth[key])
                row += f" {true:>12.6g} {100 * (values[name] - true) / true:>+7.3f}%"
            lines.append(row)
        lines.append(f"{circuit:<9} {'rms':<5} {values['rms']:>12.4g} {'':>11} A")
    return "\n".join(lines)
