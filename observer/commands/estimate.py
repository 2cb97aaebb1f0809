"""``dcobserver estimate``: estimate the winding parameters of a recording.

Before estimating, the recording is checked against what a DC motor can be
(:mod:`observer.estimation.plausibility`): an impossible one is a one-line
error, an unusual one a warning naming the likely cause. Each parameter is
marked ``ok`` or ``none`` (not identified by this recording) by the daemon's
rule (:mod:`observer.estimation.identifiability`, limits ``[observer.quality]``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="REC", help="recording: .csv, .csv.gz or .mcap")
    parser.add_argument(
        "--circuit", choices=("both", "field", "armature"), default="both",
        help="which winding to estimate",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--config", metavar="TOML",
        help="config file: [estimate] narrows the search, [observer.quality] sets what counts "
        "as identified",
    )  # fmt: skip
    add_units_option(parser)
    parser.add_argument(
        "--particles", type=int, default=None, help="swarm size (default: 100, or the config's)"
    )
    parser.add_argument(
        "--iterations", type=int, default=None,
        help="swarm iterations (default: 100, or the config's)",
    )  # fmt: skip
    parser.add_argument(
        "--schedule", default=None, choices=("s-k", "k-s", "social", "individual"),
        help="PSO coefficient schedule (default: s-k, or the config's)",
    )  # fmt: skip
    parser.add_argument(
        "--seed", type=int, default=None, help="seed of the swarm (default: 0, or the config's)"
    )
    parser.add_argument(
        "--no-polish", action="store_true",
        help="report the swarm's best as is (no Levenberg-Marquardt refinement)",
    )  # fmt: skip


def add_units_option(parser: argparse.ArgumentParser) -> None:
    """``--units``: read a recording whose columns are not in SI units."""
    parser.add_argument(
        "--units", metavar="COL=UNIT[,...]", default=None,
        help="the recording's columns are in these units, e.g. t=ms,ia=mA,omega=rpm "
        "(t: s ms us ns; va, vf: V mV kV; ia, if: A mA kA; omega: rad/s rpm Hz deg/s; "
        "-UNIT inverts the sign; default: SI)",
    )  # fmt: skip


def read_checked(path: str, units: str | None, notes: list[str] | None = None) -> Any:
    """The recording at ``path``, converted to SI by a ``--units`` specification.

    ``notes`` collects what the reader noticed (an MCAP file cut short); without
    it they are logged as warnings.
    """
    from observer.cli import UserError
    from observer.recording import parse_units, read_recording, to_si

    factors = None
    if units is not None:
        try:
            factors = parse_units(units)
        except ValueError as exc:
            raise UserError(f"--units: {exc}") from None
    rec = read_recording(path, notes=notes)
    if factors:
        from observer.recording import RecordingError

        try:
            rec = to_si(rec, factors)
        except RecordingError as exc:
            raise UserError(f"{path}: {exc}") from None
    return rec


def circuits_of(rec: Any, requested: str, path: str) -> tuple[str, ...]:
    """The circuits to estimate; a one-line error that says what the recording allows."""
    from observer.cli import UserError
    from observer.estimation import CIRCUIT_CHANNELS

    circuits = ("field", "armature") if requested == "both" else (requested,)
    possible = [c for c in ("field", "armature") if rec.has(*CIRCUIT_CHANNELS[c])]
    missing = [c for c in circuits if c not in possible]
    if not missing:
        return circuits
    have = ", ".join(("t", *rec.channels))
    need = ", ".join(CIRCUIT_CHANNELS[missing[0]])
    if possible:
        raise UserError(
            f"{path}: the {missing[0]} circuit needs {need}; the recording has {have}: "
            f"use --circuit {possible[0]}"
        )
    raise UserError(
        f"{path}: the recording has {have}: not enough for either circuit "
        "(field: vf, if; armature: va, ia, if, omega)"
    )


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.commands.display import finite_json, print_warnings, report_findings
    from observer.config import MAX_PARTICLES, Config, load_config
    from observer.estimation import (
        EstimationError,
        check_data,
        check_estimates,
        estimate_recording,
        identify,
    )
    from observer.estimation.result import kphi

    config = load_config(args.config) if args.config else Config()
    settings = config.estimate
    overrides = {
        "particles": args.particles,
        "iterations": args.iterations,
        "schedule": args.schedule,
        "seed": args.seed,
    }
    settings = settings.replace(**{k: v for k, v in overrides.items() if v is not None})
    if args.no_polish:
        settings = settings.replace(polish=False)
    if not 2 <= settings.particles <= MAX_PARTICLES or settings.iterations < 1:
        raise UserError(f"--particles must be 2-{MAX_PARTICLES} and --iterations >= 1")
    # Warnings are printed with the result: a failure on the way is then one line.
    warnings: list[str] = []
    rec = read_checked(args.recording, args.units, notes=warnings)
    circuits = circuits_of(rec, args.circuit, args.recording)
    signals = dict(rec.signals)
    findings = check_data(signals, rec.dt, circuits, t=rec.t)
    warnings += report_findings("estimate", findings, path=args.recording, defer=True)
    chain = config.chain if args.config else None
    try:
        results = estimate_recording(rec, circuits, settings, path=args.recording, chain=chain)
    except EstimationError as exc:
        # A warning often says why (a stuck sensor, a scaling): keep it on the one line.
        raise EstimationError(f"{exc} (after: {warnings[0]})" if warnings else str(exc)) from None
    quality = config.observer.quality
    limits = {c: quality.limits(c) for c in results}
    idents = {c: identify(est, limits[c]) for c, est in results.items()}
    later = check_estimates(results, idents, signals)
    warnings += report_findings("estimate", later, path=args.recording, defer=True)
    print_warnings("estimate", warnings)
    # A warning about a circuit puts its identified values in doubt: "suspect", not "ok".
    doubted = {c for f in [*findings, *later] for c in f.circuits}
    if_mean = float(np.mean(rec["if"])) if rec.has("if") else None
    report: dict[str, Any] = {}
    for name, est in results.items():
        d = est.to_dict()
        d["quality"] = {
            p: ("suspect" if q == "ok" and name in doubted else q)
            for p, q in idents[name].quality().items()
        }
        d["not_identified"] = dict(idents[name].reasons)
        if name == "armature" and if_mean is not None and est.emf_constant_h is not None:
            d["if_mean"] = if_mean
            d["kphi"], d["kphi_std"] = kphi(est.emf_constant_h, est.std.get("K", math.nan), if_mean)
        report[name] = d
    truth = rec.metadata.get("motor")
    if args.json:
        out = {
            **report,
            "recording": {
                "path": args.recording,
                "n_samples": rec.n_samples,
                "sample_rate_hz": rec.sample_rate_hz,
                "duration_s": rec.duration_s,
            },
            "limits": {"rel_std": limits},
            "warnings": warnings,
            "units": {
                **_json_units(),
                "recording": {"sample_rate_hz": "Hz", "duration_s": "s"},
            },
        }
        json.dump(finite_json(out), sys.stdout, indent=None, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(_describe(rec, args.recording))
        print("\n".join(_table(report, dict(truth) if isinstance(truth, Mapping) else None)))
        for line in _notes(report, limits, warnings):
            print(line)
    return 0


def _json_units() -> dict[str, str]:
    from observer.commands.display import UNITS

    keys = ["R", "L", "K", "kphi", "kphi_std", "tau", "rms", "i0", "if_mean", "std", "rel_std"]
    keys += ["input_noise_var", "search_range"]
    return {k: UNITS[k] for k in keys}


def _describe(rec: Any, path: str) -> str:
    from observer.commands.display import eng

    return (
        f"{path}: {rec.n_samples} samples at {eng(rec.sample_rate_hz, 'Hz', 4)} "
        f"({eng(rec.duration_s, 's', 4)}), channels {', '.join(rec.channels)}"
    )


_TRUTH_KEYS = {
    ("field", "R"): "field_resistance_ohm",
    ("field", "L"): "field_inductance_h",
    ("armature", "R"): "armature_resistance_ohm",
    ("armature", "L"): "armature_inductance_h",
    ("armature", "K"): "emf_constant_h",
}


def _table(report: dict[str, Any], truth: dict[str, Any] | None) -> list[str]:
    from observer.commands.display import NAMES, eng, eng_pair, percent, table
    from observer.commands.display import UNITS as _UNITS

    header = ["circuit", "param", "estimate", "+-1 sigma", "rel std", "quality"]
    if truth:
        header += ["true", "error"]
    rows: list[list[str]] = [header]

    def extra(cells: list[str]) -> list[str]:
        return cells + ["", ""] if truth else cells

    for circuit, values in report.items():
        quality = values["quality"]
        for name in ("R", "L", "K"):
            if name not in values:
                continue
            value, std = eng_pair(values[name], values["std"].get(name), _UNITS[name])
            row = [circuit, NAMES[(circuit, name)], value, std]
            row += [percent(values["rel_std"].get(name)), quality[name]]
            key = _TRUTH_KEYS.get((circuit, name))
            if truth:
                if key in truth:
                    true = float(truth[key])
                    error = percent((values[name] - true) / true, signed=True)
                    row += [eng(true, _UNITS[name]), error]
                else:
                    row += ["", ""]
            rows.append(row)
            if name == "L":
                tau = eng(values["tau"], "s")
                rows.append(extra([circuit, "tau", tau, "", "", quality["L"]]))
            if name == "K" and "kphi" in values:
                kphi, kphi_std = eng_pair(values["kphi"], values.get("kphi_std"), "V*s/rad")
                rows.append(extra([circuit, "kPhi", kphi, kphi_std, "", quality["K"]]))
        rows.append(extra([circuit, "fit rms", eng(values["rms"], "A"), "", "", ""]))
    return table(rows, "<<>>><" + ("><" if truth else ""))


def _notes(
    report: dict[str, Any], limits: Mapping[str, Mapping[str, float]], warnings: list[str]
) -> list[str]:
    from observer.commands.display import K_EXPLAINED, NAMES, eng
    from observer.estimation import dealias

    lines = []
    # Parameters that share a reason (a window the model cannot describe says it for each
    # of its circuit's parameters) are named together: "Ra, La, K (reason)".
    by_reason: dict[str, list[str]] = {}
    for c, values in report.items():
        for p, reason in values["not_identified"].items():
            by_reason.setdefault(reason, []).append(NAMES[(c, p)])
    missing = [f"{', '.join(names)} ({reason})" for reason, names in by_reason.items()]
    limit_text = ", ".join(
        f"{NAMES[(c, p)]} {100 * v:g} %" for c, lim in limits.items() for p, v in lim.items()
    )
    if missing:
        lines.append(
            "not identified by this recording (quality none; do not use these values): "
            + "; ".join(missing)
        )
    suspect = any("suspect" in values["quality"].values() for values in report.values())
    lines.append(
        f"quality: ok = identified (relative std within [observer.quality]: {limit_text}); "
        + ("suspect = identified, but a warning below doubts the data; " if suspect else "")
        + "none = not identified"
    )
    for c, values in report.items():
        fit = values.get("voltage_filter")
        if fit is None:
            continue
        if fit["alias"] is not None:
            put_back = (
                ", its jumps put back between the samples through it"
                if (c in dealias.WINDINGS)
                else ""
            )
            lines.append(
                f"{c} voltage filter (front ends not configured): {fit['text']}, as "
                f"{fit['jumps']} of the converter's jumps show it{put_back}; tell [chain] the "
                "real one"
            )
        else:
            lines.append(
                f"{c} voltage filter (front ends not configured): not identified "
                f"({fit['reason']}); an RC at fs/4, the weakest in use, assumed"
            )
    linearity = (report.get("armature") or {}).get("voltage_linearity") or {}
    fold = linearity.get("fold") if isinstance(linearity, dict) else None
    if isinstance(fold, dict) and fold.get("taken_out"):
        lines.append(
            "armature voltage: a converter's pulses fold onto the reading as a curve periodic "
            f"in the voltage (period {fold['period_v']:.0f} V, {fold['rms_v']:.2g} V rms, "
            f"{100 * fold['share']:.0f} % of the slow equation error); taken out of the samples "
            "before the armature was estimated"
        )
    for c, values in report.items():
        part = values.get("operating_point_std") or {}
        # Named where it is most of the std (over a quarter of its variance).
        named = [
            f"{NAMES[(c, p)]} {100 * v / abs(values[p]):.2g} %"
            for p, v in part.items()
            if values.get(p) and v > 0.5 * values["std"].get(p, 0.0)
        ]
        if named:
            lines.append(
                f"{c}: the fits over the recording's low- and high-voltage halves disagree "
                f"beyond their noise ({', '.join(named)} of the value as one sigma, in the std): "
                "the reading's error depends on the operating point (a converter's pulses "
                "folded through the front end onto zero frequency, a transducer's curve); "
                "sample at a rate no harmonic of the pulses lands on, filter the voltage more "
                "steeply, or measure it averaged over each period"
            )
    arm = report.get("armature")
    if arm and "K" in arm:
        at = f" at the mean field current ({eng(arm['if_mean'], 'A')})" if "kphi" in arm else ""
        lines.append(K_EXPLAINED.format(at=at))
    lines += [f"warning: {w}" for w in warnings]
    return lines
