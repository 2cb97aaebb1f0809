"""``dcobserver router``: a Zenoh router for a fleet, with dcobserver's security options.

Daemons (``[zenoh] mode = "client"``) and subscribers connect to it; it routes
between them and enforces ``[zenoh.access]``: each drive's keys published only
by that drive's identities, read only by the listed subscribers. It is a Zenoh
session in router mode in this process, for sites without ``zenohd`` (which
reads the same ``transport`` and ``access_control`` settings: print them with
``--print-zenoh-config``).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from observer.config import ZenohLinkConfig

log = logging.getLogger("dcobserver.router")

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", metavar="TOML", default=None,
        help="a file with a [zenoh] table: listen, [zenoh.tls], [zenoh.auth], [zenoh.access] "
        "(config/fleet/router.toml)",
    )  # fmt: skip
    parser.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help=f"listen here, repeatable; without it the --config file's, else {DEFAULT_LISTEN}",
    )  # fmt: skip
    parser.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help="another router to join, repeatable; without it the --config file's",
    )  # fmt: skip
    parser.add_argument(
        "--print-zenoh-config", action="store_true",
        help="print the Zenoh configuration as JSON (for zenohd -c) and exit",
    )  # fmt: skip


def describe(link: ZenohLinkConfig) -> list[str]:
    """What the router enforces, one line each (logged at start)."""
    tls = link.tls
    lines = [
        "TLS: "
        + (
            ("mutual, " if tls.mutual else "server only, ") + f"CA {tls.root_ca}"
            if tls.enabled
            else "off"
        ),
        "user/password: "
        + (f"required ({link.auth.dictionary_file})" if link.auth.dictionary_file else "off"),
    ]
    access = link.access
    if not access.enabled:
        lines.append("access control: off (any connected party may publish and subscribe)")
        return lines
    by = "certificate CN" if access.identify_by == "common_name" else "user"
    for drive, identities in sorted(access.publishers.items()):
        lines.append(
            f"access: dcobserver/{drive}/** published only by {by} {', '.join(identities)}"
        )
    subscribers = ", ".join(access.subscribers) or "nobody"
    lines.append(f"access: dcobserver/** read by {by} {subscribers}; everything else denied")
    return lines


def main(args: argparse.Namespace) -> int:
    import zenoh

    from observer.cli import UserError
    from observer.commands.subscribe import session_link
    from observer.service import sdnotify
    from observer.service.zenohconf import session_config

    link = session_link(args, default_listen=[DEFAULT_LISTEN], default_connect=())
    config = session_config(link, "router")
    if args.print_zenoh_config:
        print(json.dumps(config, indent=2))
        return 0
    try:
        session = zenoh.open(zenoh.Config.from_json5(json.dumps(config)))
    except Exception as exc:
        first = str(exc).split(" at /")[0].splitlines()[0] if str(exc) else repr(exc)
        raise UserError(f"cannot start the router: {first}") from None

    stop = threading.Event()

    def on_signal(_signum: int, _frame: object) -> None:
        stop.set()

    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, on_signal)
    for line in describe(link):
        log.info("%s", line)
    listen = ", ".join(link.listen) or "-"
    log.info("router %s listening on %s", session.info.zid(), listen)
    sdnotify.ready(f"routing on {listen}")
    try:
        while not stop.wait(1.0):
            pass
    finally:
        sdnotify.stopping()
        session.close()
    log.info("router stopped")
    return 0
