"""``dcobserver diagnose``: locate model mismatch, name the missing physics, fit it."""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording", metavar="REC", nargs="+",
        help="recording: .csv, .csv.gz or .mcap; several, a folder or a glob: one table of "
        "every recording's verdict (see below)",
    )  # fmt: skip
    parser.add_argument("--json", metavar="OUT.json", default=None, help="write the result as JSON")
    parser.add_argument(
        "--report", metavar="OUT.html", default=None, help="write a self-contained HTML report"
    )
    parser.add_argument(
        "--effects", default=None, metavar="NAME[,NAME...]",
        help="test only these effects (default: all of field_saturation, thermal_drift, "
        "brush_drop, armature_reaction, eddy_currents, sensor_offset, sampling_skew)",
    )  # fmt: skip
    parser.add_argument("--particles", type=int, default=24, help="swarm size of each extension")
    parser.add_argument("--iterations", type=int, default=40, help="swarm iterations per extension")
    parser.add_argument("--seed", type=int, default=0, help="seed of the swarms")
    parser.add_argument(
        "--config", metavar="FILE", default=None,
        help="dcobserver config whose [chain] (intersample model, front ends) the diagnosis "
        "uses (default: none, decided from the data)",
    )  # fmt: skip
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    from observer.commands.archive import add_options
    from observer.commands.estimate import add_units_option

    add_units_option(parser)
    add_options(
        parser,
        "every recording's verdict (verdict, accepted effects, the verdict's parameters, "
        "the baseline's field.* and armature.* as in --json, mismatch count, chain "
        "findings, warnings)",
    )


@dataclass(frozen=True)
class Options:
    """What ``diagnose`` does to each recording (checked; the same for every file)."""

    effects: tuple[str, ...] | None
    particles: int
    iterations: int
    seed: int
    chain: Any
    units: str | None
    #: The drive and motor of a recording whose metadata names none.
    config: Any


def _options(args: argparse.Namespace) -> Options:
    """The checked options of the command line (a one-line error for a bad one)."""
    from observer.cli import UserError
    from observer.config import MAX_PARTICLES, Config, load_config
    from observer.diagnosis.effects import LIBRARY

    if not 2 <= args.particles <= MAX_PARTICLES or args.iterations < 0:
        raise UserError(f"--particles must be 2-{MAX_PARTICLES} and --iterations >= 0")
    effects = None
    if args.effects:
        effects = tuple(e.strip() for e in args.effects.split(",") if e.strip())
        bad = [e for e in effects if e not in LIBRARY]
        if bad:
            raise UserError(f"unknown effect(s) {', '.join(bad)}; expected {', '.join(LIBRARY)}")
    config = load_config(args.config) if args.config else Config()
    return Options(
        effects=effects, particles=args.particles, iterations=args.iterations, seed=args.seed,
        chain=config.chain if args.config else None, units=args.units, config=config,
    )  # fmt: skip


def _diagnose(path: str, options: Options, *, progress: bool, defer: bool) -> tuple[Any, Any, list]:
    """``(diagnosis, recording, warnings)`` of one recording: the command's work.

    Raises
    ------
    observer.cli.UserError
        (and the readers' errors) for a recording that cannot be diagnosed.
    """
    from observer.cli import UserError
    from observer.commands.display import report_findings
    from observer.commands.estimate import read_checked
    from observer.diagnosis.diagnose import diagnose
    from observer.diagnosis.fitting import split_segments
    from observer.estimation import EstimationError, check_data

    rec = read_checked(path, options.units)
    rec.require("va", "ia", "vf", "if", "omega", path=path, purpose="a diagnosis")
    findings = check_data(dict(rec.signals), rec.dt, ("field", "armature"), t=rec.t)
    errors = [f for f in findings if f.severity == "error"]
    if not errors:  # too short for a diagnosis: its one line, not a warning and an error
        try:
            split_segments(rec.n_samples, rec.dt, rec.n_samples)
        except EstimationError as exc:
            raise UserError(f"{path}: {exc}") from None
    warnings = report_findings("diagnose", findings, path=path, defer=defer)
    diag = diagnose(
        rec, effects=list(options.effects) if options.effects else None,
        n_particles=options.particles, iterations=options.iterations,
        seed=options.seed, progress=progress, path=path, chain=options.chain,
    )  # fmt: skip
    return diag, rec, warnings


def _result(diag: Any, warnings: list[str]) -> dict[str, Any]:
    """The ``--json`` document of a diagnosis."""
    from observer.diagnosis.effects import LIBRARY

    param_units = {
        p.name: ("1" if p.unit == "-" else p.unit)
        for effect in LIBRARY.values()
        for p in effect.parameters(diag.context)
    }
    units = {**JSON_UNITS, "params": {**param_units, **MAGNITUDE_UNITS}}
    return {**diag.to_dict(), "warnings": warnings, "units": units}


def verdict_row(path: str, options: Options) -> tuple[list[dict[str, Any]], list[str]]:
    """One recording's verdict as one table row, and its warnings.

    The work of ``dcobserver diagnose REC`` (same checks and diagnosis), for
    :func:`observer.commands.archive.run_files`; the values are those of its
    ``--json``.

    Raises
    ------
    observer.cli.UserError
        (and the readers' errors) for a recording that cannot be diagnosed.
    """
    from observer.commands.archive import flatten, recording_ids
    from observer.commands.display import finite_json

    diag, rec, warnings = _diagnose(path, options, progress=False, defer=True)
    result = finite_json(_result(diag, warnings))
    best = next((f for f in result["findings"] if f["effect"] == diag.verdict), None)
    row: dict[str, Any] = {
        **recording_ids(path, options.config, rec.metadata),
        "verdict": result["verdict"],
        "description": result["description"],
        "accepted": ",".join(f.effect for f in diag.findings if f.accepted),
        "verdict_params": json.dumps(best["params"], separators=(",", ":")) if best else "",
    }
    for circuit in ("field", "armature"):
        baseline = dict(result["baseline"][circuit])
        baseline.pop("search_range", None)
        row.update(flatten(baseline, f"{circuit}."))
    row["mismatch"] = len(result["mismatch"])
    row["chain"] = ",".join(f"{c['kind']}:{c['channel']}" for c in result["chain"])
    row["warnings"] = " | ".join(warnings)
    return [row], warnings


def main(args: argparse.Namespace) -> int:
    from observer.commands.archive import run_table_command, wants_table
    from observer.commands.display import eng, finite_json
    from observer.commands.outputs import check_outputs, write_text

    options = _options(args)
    if wants_table(args):
        return run_table_command(
            "diagnose", args, verdict_row, options, progress=not args.quiet,
            one_file_options=("--json", "--report"), what="every recording's verdict",
        )  # fmt: skip
    path = args.recording[0]
    inputs = [path, *([args.config] if args.config else [])]
    check_outputs(("--json", args.json), ("--report", args.report), inputs=inputs)
    diag, rec, warnings = _diagnose(path, options, progress=not args.quiet, defer=False)
    result = _result(diag, warnings)
    if args.json:
        write_text(args.json, json.dumps(finite_json(result), indent=1, allow_nan=False) + "\n")
    if args.report:
        from observer.diagnosis.report import render_html

        write_text(args.report, render_html(diag, rec, title=f"dcobserver diagnosis of {path}"))
    print(f"verdict: {diag.verdict}")
    print(diag.description)
    for m in diag.mismatch[:5]:
        print(f"  mismatch {m.t0:.2f}-{m.t1:.2f} s on {m.channel}: {m.conditions}")
    for f in diag.findings[:3]:
        ev = f.evidence
        print(
            f"  {f.effect:<34} {'earns it' if f.accepted else 'rejected':<9} "
            f"held-out {100 * ev['holdout_gain']:+.2f} % (LR {ev['holdout_lr']:.1f}), "
            f"rms {f.channel} {eng(f.rms_before, 'A')} -> {eng(f.rms_after, 'A')}"
        )
    for c in diag.chain:
        print(f"  chain {c.kind} on {c.channel}: {c.advice}")
    for w in warnings:
        print(f"warning: {w}")
    return 0


#: The units of ``--json``: the baseline's as ``dcobserver estimate``'s; effect
#: parameters carry their unit in their names (``brush_drop_v``, ``..._ohm``).
JSON_UNITS: dict[str, Any] = {
    "baseline": {"R": "ohm", "L": "H", "K": "H", "tau": "s", "rms": "A", "std": "as the value"},
    "noise_floor": {"rms": "A", "white_rms": "A", "coloured_rms": "A", "tau_int_samples": "1"},
    "mismatch": {"t0": "s", "t1": "s", "z": "1"},
    "findings": {"rms_before": "A", "rms_after": "A", "params": "see params"},
}
#: The plain-words magnitudes among a finding's params (the rest: the effects' own).
MAGNITUDE_UNITS: dict[str, str] = {
    "flux_deficit_at_peak_if": "1",
    "resistance_rise_at_end": "1",
    "flux_loss_at_peak_ia": "1",
    "delay_samples": "samples",
}
