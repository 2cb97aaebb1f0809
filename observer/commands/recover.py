"""``dcobserver recover``: rewrite a truncated MCAP log (crash, power loss) as a valid one.

The result appears only when complete; an existing result is never replaced
unless ``--force`` (a second ``recover`` must not silently undo the first);
a file that is not MCAP, or holds no complete message, is an error.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger("dcobserver.recover")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="the truncated .mcap file")
    parser.add_argument(
        "-o", "--output", metavar="OUT", default=None,
        help="where to write (default: FILE with .recovered.mcap); FILE itself is never touched "
        "unless --in-place",
    )  # fmt: skip
    parser.add_argument("--in-place", action="store_true", help="replace FILE by the result")
    parser.add_argument(
        "-f", "--force", action="store_true", help="replace OUT if it exists (default: refuse)"
    )


def output_path(src: str) -> str:
    """The default result of recovering ``src``: ``X.mcap`` -> ``X.recovered.mcap``."""
    stem = src[:-5] if src.lower().endswith(".mcap") else src
    return stem + ".recovered.mcap"


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.commands.outputs import check_input
    from observer.recording import check_writable
    from observer.service.mcaplog import recover

    if args.in_place and args.output:
        raise UserError("give either --output or --in-place")
    src = args.file
    check_input(src)
    out = src if args.in_place else (args.output or output_path(src))
    overwrite = args.in_place or args.force
    if not overwrite and Path(out).exists():
        raise UserError(f"{out} exists; give --force to replace it, or --output elsewhere")
    if Path(out).resolve() == Path(src).resolve() and not args.in_place:
        raise UserError(f"{out} is FILE itself; give --in-place to replace it")
    try:
        check_writable(out)
        n = recover(src, out, overwrite=overwrite)
    except FileExistsError:
        raise UserError(f"{out} appeared meanwhile; give --force to replace it") from None
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    print(f"{out}: {n} messages recovered")
    return 0
