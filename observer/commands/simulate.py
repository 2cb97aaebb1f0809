"""``dcobserver simulate``: write a recording of a simulated DC drive."""

from __future__ import annotations

import argparse
import logging
import math

log = logging.getLogger(__name__)

#: The most samples one recording may have: an hour at 20 kHz fits, a typo (1e9 s) is an
#: error instead of an allocation of terabytes.
MAX_SAMPLES = 1e8


def configure(parser: argparse.ArgumentParser) -> None:
    from observer.estimation.motor import MOTORS

    parser.add_argument("output", metavar="OUT", help="file to write: .csv, .csv.gz or .mcap")
    parser.add_argument("--motor", choices=sorted(MOTORS), default="p12", help="motor to simulate")
    parser.add_argument("--duration", type=float, default=20.0, metavar="S", help="length (s)")
    parser.add_argument("--rate", type=float, default=2000.0, metavar="HZ", help="sample rate (Hz)")
    parser.add_argument(
        "--noise", type=float, default=0.002, metavar="FRACTION",
        help="sensor noise, as a fraction of each channel's rated value",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=0, help="seed of duty cycle and noise")
    parser.add_argument(
        "--circuit", choices=("both", "field", "armature"), default="both",
        help="write only the channels one circuit needs",
    )  # fmt: skip
    parser.add_argument(
        "--effect", default=None, metavar="NAME[=MAG][,NAME...]",
        help="physics the plain model leaves out: field_saturation (flux deficit at rated "
        "field current, default 0.08), thermal_drift (resistance rise at rated currents, 0.3), "
        "brush_drop (V, 1.0), armature_reaction (flux loss at rated current, 0.05), "
        "eddy_currents (coupling k^2, 0.2), sensor_offset (ia offset / rated current, 0.01), "
        "sampling_skew (current delay in sample periods, 0.5); outside the diagnosis library "
        "(recordings that diagnosis must call unexplained): emf_ripple (back-EMF ripple, 8 per "
        "revolution, 0.02), tacho_error (speed reading's loss at rated current, 0.01)",
    )  # fmt: skip
    parser.add_argument(
        "--thermal-tau", type=float, default=20.0, metavar="S",
        help="thermal time constant of the windings under --effect thermal_drift (s)",
    )  # fmt: skip
    parser.add_argument(
        "--change", default=None, metavar="TARGET=REL@S[,...]",
        help="steps at given times: a parameter (Rf, Lf, Ra, La, K) or the tachometer's gain "
        "(tach) is multiplied by 1+REL from S seconds on, e.g. Ra=+0.03@30 (a loose "
        "connection), K=-0.05@60 (a field fault), tach=-0.1@40 (the tachometer reads 10 %% low)",
    )  # fmt: skip
    from observer.commands.drive_options import add_drive_options

    add_drive_options(parser)


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.commands.drive_options import drive_from_args
    from observer.commands.outputs import check_outputs
    from observer.estimation.motor import MOTORS
    from observer.recording import write_recording
    from observer.simulation.simulate import simulate

    finite = all(math.isfinite(x) for x in (args.duration, args.rate, args.noise))
    if not (finite and args.duration > 0 and args.rate > 0 and args.noise >= 0):
        raise UserError("--duration and --rate must be finite and > 0, --noise finite and >= 0")
    if args.duration * args.rate > MAX_SAMPLES:
        raise UserError(
            f"--duration {args.duration:g} s at --rate {args.rate:g} Hz is "
            f"{args.duration * args.rate:.3g} samples; at most {MAX_SAMPLES:.0e} (an hour at "
            "20 kHz is 7.2e7)"
        )
    if not args.output.lower().endswith((".csv", ".csv.gz", ".mcap")):
        raise UserError(f"{args.output}: expected a name ending in .csv, .csv.gz or .mcap")
    check_outputs(("OUT", args.output))
    motor = MOTORS[args.motor]
    from observer.simulation.effects_sim import Change, parse_changes, parse_effects

    effects = None
    if args.effect is not None:
        try:
            effects = parse_effects(args.effect)
        except ValueError as exc:
            raise UserError(f"--effect: {exc}") from None
    changes: tuple[Change, ...] = ()
    if args.change is not None:
        try:
            changes = parse_changes(args.change)
        except ValueError as exc:
            raise UserError(f"--change: {exc}") from None
    if not args.thermal_tau > 0:
        raise UserError(f"--thermal-tau must be > 0, got {args.thermal_tau}")
    drive, drive_name = drive_from_args(args, args.rate)
    try:
        rec = simulate(
            motor, duration_s=args.duration, sample_rate_hz=args.rate, noise=args.noise,
            seed=args.seed, effects=effects, changes=changes,
            thermal_time_constant_s=args.thermal_tau, drive=drive, drive_name=drive_name,
        )  # fmt: skip
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if args.circuit == "field":
        rec = rec.select("vf", "if")
    elif args.circuit == "armature":
        rec = rec.select("va", "ia", "if", "omega")
    try:
        write_recording(rec, args.output)  # atomic: Ctrl-C leaves no partial file
    except OSError as exc:
        raise UserError(f"cannot write {args.output}: {exc.strerror or exc}") from exc
    log.info(
        "wrote %s: %s, %d samples at %g Hz (%g s), drive %s",
        args.output, motor.name, rec.n_samples, args.rate, rec.duration_s, drive_name,
    )  # fmt: skip
    return 0
