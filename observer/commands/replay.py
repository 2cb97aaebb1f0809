"""``dcobserver replay``: run the observer over a recording or daemon log, as fast as possible."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording", metavar="FILE", help=".mcap (a recording or daemon log) or .csv"
    )
    parser.add_argument(
        "--config", metavar="TOML", default=None,
        help="take [observer] (windows, seed, swarm) from this file; default: built-in defaults",
    )  # fmt: skip
    parser.add_argument("--json", action="store_true", help="print each estimate as a JSON line")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def main(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from observer.cli import UserError
    from observer.commands.run import format_estimate
    from observer.config import Config, load_config
    from observer.service.daemon import run_offline
    from observer.service.mcaplog import to_json
    from observer.service.window_observer import WindowResult
    from observer.service.zenohconf import names
    from replay.source import ReplayOptions, ReplaySource

    config = load_config(args.config) if args.config else Config()
    if not Path(args.recording).is_file():
        raise UserError(f"{args.recording}: file not found")
    source = ReplaySource(ReplayOptions(path=args.recording, speed=0.0, block_s=0.1))
    bar = tqdm(
        unit="sample", unit_scale=True, disable=args.no_progress, file=sys.stderr,
        desc=Path(args.recording).name,
    )  # fmt: skip
    ids = names(config.observer.drive_id, config.observer.motor_id)

    def on_result(result: WindowResult) -> None:
        if result.estimate is None:
            return
        estimate = {**ids, **result.estimate}
        if args.json:
            sys.stdout.write(to_json(estimate).decode() + "\n")
        else:
            bar.write(format_estimate(estimate))

    try:
        observer = run_offline(config, source, on_result=on_result, progress=bar.update)
    finally:
        bar.close()
    summary = observer.health()
    print(json.dumps({"summary": summary["windows"]}), file=sys.stderr)
    return 0
