"""Options of the simulated drive shared by ``simulate`` and ``fake-drive``: the converters and
the measurement chain (``docs/drive_chain.md``).

Precedence: the ``--preset``, then the ``--chain`` file, then the single options. The
``--chain`` file's ``[chain]`` is the estimator's (:class:`observer.config.ChainConfig`), so one
description of a front end serves ``simulate`` and ``estimate --config``. Per-channel
options take ``VALUE`` for every channel, ``CH=VALUE,...`` for some, or both
(``butter2@fs/4,va=none``). Bad values end in one line naming the option (exit status 2).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from observer.simulation.converter import DriveSpec

#: option -> ConverterSpec field (numbers)
_CONVERTER_NUMBERS = {
    "mains_hz": "mains_hz",
    "line_voltage": "line_voltage_v",
    "field_supply": "field_supply_v",
    "dc_link": "dc_link_v",
    "source_inductance": "source_inductance_h",
    "switching_hz": "switching_hz",
    "dead_time": "dead_time_s",
}


def _by_preset(value: Callable[[DriveSpec], str]) -> str:
    """``default per --preset: ideal: X, realistic: Y``: an option's default under each preset."""
    from observer.simulation.converter import PRESETS, ConverterSpec, DriveSpec

    ideal = DriveSpec(ConverterSpec(armature="ideal", field="ideal"))
    return "default per --preset: " + ", ".join(
        f"{name}: {value(spec or ideal)}" for name, spec in PRESETS.items()
    )


def add_drive_options(parser: argparse.ArgumentParser) -> None:
    """Add the converter and chain options to ``parser``."""
    from observer.simulation.converter import (
        ARMATURE_KINDS,
        DEFAULT_PRESET,
        FIELD_KINDS,
        PRESETS,
        ConverterSpec,
    )

    spec = ConverterSpec()
    g = parser.add_argument_group(
        "converter and measurement chain (equations: docs/drive_chain.md)",
        "Precedence: --preset, then the --chain file, then these options. Per-channel options "
        "take VALUE for every channel, CH=VALUE,... for some (channels va, ia, vf, if, omega), "
        "or both: 'butter2@fs/4,va=none'. A default 'sized' is derived from the motor's "
        "ratings (docs/drive_chain.md, Sizing).",
    )
    g.add_argument(
        "--preset", default=DEFAULT_PRESET, metavar="NAME",
        help=f"drive to start from: {', '.join(PRESETS)}. 'ideal': voltages held per sample, no "
        "front end; 'realistic': thyristor-6p armature, bridge-1p field, butter2@fs/4 on every "
        "channel, 12-bit ADC, --noise on every channel",
    )  # fmt: skip
    g.add_argument(
        "--converter", metavar="KIND", default=argparse.SUPPRESS,
        help=f"armature converter: {', '.join(ARMATURE_KINDS)} "
        f"({_by_preset(lambda d: d.converter.armature)})",
    )  # fmt: skip
    g.add_argument(
        "--field-converter", metavar="KIND", default=argparse.SUPPRESS,
        help=f"field converter: {', '.join(FIELD_KINDS)} "
        f"({_by_preset(lambda d: d.converter.field)})",
    )  # fmt: skip
    g.add_argument(
        "--mains-hz", type=float, metavar="HZ", default=argparse.SUPPRESS,
        help=f"mains frequency of the bridges (default {spec.mains_hz:g})",
    )  # fmt: skip
    g.add_argument(
        "--line-voltage", type=float, metavar="V", default=argparse.SUPPRESS,
        help="RMS line voltage of the armature bridge (default: sized, 1.35*V*cos(15 deg) = "
        "1.15x rated armature voltage)",
    )  # fmt: skip
    g.add_argument(
        "--field-supply", type=float, metavar="V", default=argparse.SUPPRESS,
        help="RMS supply of the field bridge, or the field chopper's DC link (default: sized, "
        "1.5x rated field voltage at 15 deg; chopper 1.6x)",
    )  # fmt: skip
    g.add_argument(
        "--dc-link", type=float, metavar="V", default=argparse.SUPPRESS,
        help="DC link of the armature chopper (default: sized, 1.2x rated armature voltage)",
    )  # fmt: skip
    g.add_argument(
        "--source-inductance", type=float, metavar="H", default=argparse.SUPPRESS,
        help="commutating inductance per phase; > 0 gives commutation overlap; in series with "
        f"the armature for the chopper (default {spec.source_inductance_h:g})",
    )  # fmt: skip
    g.add_argument(
        "--switching-hz", type=float, metavar="HZ", default=argparse.SUPPRESS,
        help=f"PWM carrier of the choppers (default {spec.switching_hz:g})",
    )  # fmt: skip
    g.add_argument(
        "--dead-time", type=float, metavar="S", default=argparse.SUPPRESS,
        help=f"dead time of a bridge changeover after zero current (default {spec.dead_time_s:g})",
    )  # fmt: skip
    g.add_argument(
        "--chain", metavar="FILE.toml", default=argparse.SUPPRESS,
        help="a drive file: [converter], [chain] (the estimator's grammar: [chain.CH] filter, "
        "delay_us, averaging) and [sensors] tables (example: config/drive/chain-example.toml); "
        "a dcobserver config gives its [chain] (default: none)",
    )  # fmt: skip
    g.add_argument(
        "--aa-filter", metavar="[CH=]KIND ORDER@CUTOFF,...", default=argparse.SUPPRESS,
        help="anti-aliasing filter: none, or butter|bessel|rc with order 1-4 and the -3 dB "
        "cutoff in Hz or as fs/N, e.g. butter2@fs/4, va=rc1@500 "
        f"({_by_preset(lambda d: d.chain['va'].filter_text())})",
    )  # fmt: skip
    g.add_argument(
        "--adc-bits", metavar="[CH=]BITS,...", default=argparse.SUPPRESS,
        help="ADC resolution (1-24 bits), or none "
        f"({_by_preset(lambda d: str(d.chain['va'].bits).lower())})",
    )  # fmt: skip
    g.add_argument(
        "--full-scale", metavar="[CH=]VALUE,...", default=argparse.SUPPRESS,
        help="bipolar ADC range +-VALUE in V, A or rad/s (default: sized, va and vf 1.1x the "
        "supply's peak, ia 4x and if, omega 2x rated)",
    )  # fmt: skip
    g.add_argument(
        "--delay-us", metavar="[CH=]MICROSECONDS,...", default=argparse.SUPPRESS,
        help="sampling delay behind the nominal instant, below one period (a multiplexed "
        "ADC), e.g. ia=20,if=40 (default 0)",
    )  # fmt: skip
    g.add_argument(
        "--gain-error", metavar="[CH=]FRACTION,...", default=argparse.SUPPRESS,
        help="sensor gain error, e.g. ia=0.01 (reads 1 %% high) (default 0)",
    )  # fmt: skip
    g.add_argument(
        "--offset", metavar="[CH=]VALUE,...", default=argparse.SUPPRESS,
        help="sensor offset in V, A or rad/s (default 0)",
    )  # fmt: skip
    g.add_argument(
        "--averaging", metavar="CH,...", default=argparse.SUPPRESS,
        help="channels measured by an integrating ADC (the mean over the period ending at the "
        "sample), e.g. va,vf; 'none' for no channel (default none)",
    )  # fmt: skip


def _float(text: str) -> float:
    import math

    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not finite")
    return value


def _bits(text: str) -> int | None:
    if text.strip().lower() == "none":
        return None
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"bits must be an integer or none, got {text!r}") from None


#: option -> (ChannelChain field or None for the filter, converter of one value)
_CHANNEL_OPTIONS: dict[str, tuple[str | None, Callable[[str], Any]]] = {
    "aa_filter": (None, str),
    "adc_bits": ("bits", _bits),
    "full_scale": ("full_scale", _float),
    "delay_us": ("delay_s", lambda text: _float(text) / 1e6),
    "gain_error": ("gain_error", _float),
    "offset": ("offset", _float),
}


def drive_from_args(
    args: argparse.Namespace, sample_rate_hz: float
) -> tuple[DriveSpec | None, str]:
    """The drive the options describe, and its name (the preset's, and the options that
    changed it).

    ``None`` is the ideal drive of today's simulator: the ``ideal`` preset with no option.

    Raises
    ------
    observer.cli.UserError
        One line naming the option, or the file and key.
    """
    from observer.cli import UserError
    from observer.config import parse_filter
    from observer.simulation.chain import (
        CHANNELS,
        MeasurementChain,
        apply_per_channel,
        parse_per_channel,
    )
    from observer.simulation.converter import (
        PRESETS,
        ConverterSpec,
        DriveSpec,
        load_drive_file,
    )

    if args.preset not in PRESETS:
        raise UserError(f"--preset: unknown preset {args.preset!r} (expected {', '.join(PRESETS)})")
    base = PRESETS[args.preset]
    names = ["chain", "converter", "field_converter", *_CONVERTER_NUMBERS, *_CHANNEL_OPTIONS,
             "averaging"]  # fmt: skip
    # the options default to "absent" (argparse.SUPPRESS): their defaults are the preset's
    values = {name: getattr(args, name, None) for name in names}
    given = [name for name in names if values[name] is not None]
    if not given:
        return base, args.preset
    drive = base or DriveSpec(ConverterSpec(armature="ideal", field="ideal"), MeasurementChain())

    def option(name: str) -> str:
        return "--" + name.replace("_", "-")

    def check(where: str, spec: DriveSpec, *, file: bool = False) -> DriveSpec:
        try:
            spec.chain.check_rate(sample_rate_hz)
        except ValueError as exc:
            problem = str(exc) if file else _plain(exc)
            raise UserError(f"{where}: {problem} (--rate {sample_rate_hz:g})") from None
        return spec

    if values["chain"] is not None:
        drive = check(values["chain"], load_drive_file(values["chain"], drive), file=True)
    converter_changes: dict[str, Any] = {}
    if values["converter"] is not None:
        converter_changes["armature"] = values["converter"]
    if values["field_converter"] is not None:
        converter_changes["field"] = values["field_converter"]
    for name, field in _CONVERTER_NUMBERS.items():
        if values[name] is not None:
            converter_changes[field] = values[name]
    try:
        drive = drive.replace(converter=drive.converter.replace(**converter_changes))
    except ValueError as exc:
        message = str(exc)
        renamed = {"converter": "armature", "field_converter": "field", **_CONVERTER_NUMBERS}
        for name, key in renamed.items():
            if message.startswith(f"converter.{key}:"):
                message = option(name) + message[len(f"converter.{key}") :]
                break
        raise UserError(message) from None
    for name, (chain_key, convert) in _CHANNEL_OPTIONS.items():
        text = values[name]
        if text is None:
            continue
        try:
            per = parse_per_channel(text, convert)
            if chain_key is None:
                changes = {ch: parse_filter(v) for ch, v in per.items()}
            else:
                changes = {ch: {chain_key: v} for ch, v in per.items()}
            chain = apply_per_channel(drive.chain, changes)
        except ValueError as exc:
            raise UserError(f"{option(name)} {text}: {_plain(exc)}") from None
        drive = check(f"{option(name)} {text}", drive.replace(chain=chain))
    if values["averaging"] is not None:
        chosen = [c.strip() for c in values["averaging"].split(",") if c.strip()]
        if chosen == ["none"]:
            chosen = []
        unknown = [c for c in chosen if c not in CHANNELS]
        if unknown:
            raise UserError(
                f"--averaging: unknown channel {unknown[0]!r} (expected {', '.join(CHANNELS)})"
            )
        chain = drive.chain
        for c in CHANNELS:
            chain = chain.with_channel(c, averaging=c in chosen)
        drive = drive.replace(chain=chain)
    return drive, f"{args.preset}, changed by {' '.join(option(name) for name in given)}"


def _plain(exc: ValueError) -> str:
    # A chain error names its key (chain.ia.bits: ...); on the command line the option is named.
    text = str(exc)
    if text.startswith(("chain.", "sensors.")):
        key, _, rest = text.partition(": ")
        return f"{key.split('.', 1)[1]}: {rest}"
    return text
