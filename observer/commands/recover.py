"""``dcobserver recover``: rewrite a truncated MCAP log (crash, power loss) as a valid one."""

from __future__ import annotations

import argparse
import logging
import os

log = logging.getLogger("dcobserver.recover")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", metavar="FILE", help="the truncated .mcap file")
    parser.add_argument(
        "-o", "--output", metavar="OUT", default=None,
        help="where to write (default: FILE with .recovered.mcap); FILE itself is never touched "
        "unless --in-place",
    )  # fmt: skip
    parser.add_argument("--in-place", action="store_true", help="replace FILE by the result")


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.service.mcaplog import recover

    if args.in_place and args.output:
        raise UserError("give either --output or --in-place")
    src = args.file
    if args.in_place:
        out = src + ".recovering"
    elif args.output:
        out = args.output
    else:
        stem = src[:-5] if src.endswith(".mcap") else src
        out = stem + ".recovered.mcap"
    try:
        n = recover(src, out)
    except OSError as exc:
        raise UserError(f"cannot write {out}: {exc.strerror or exc}") from None
    if args.in_place:
        os.replace(out, src)
        out = src
    print(f"{out}: {n} messages recovered")
    return 0
