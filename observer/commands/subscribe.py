"""``dcobserver subscribe``: a live table of the estimates of any drive, over Zenoh."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "keyexpr", nargs="?", default="dcobserver/*/estimate", metavar="KEYEXPR",
        help="Zenoh key expression to subscribe to",
    )  # fmt: skip
    parser.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help="endpoint of a daemon or router (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help="listen here for daemons that connect to us (repeatable)",
    )  # fmt: skip
    parser.add_argument("--mode", choices=("peer", "client"), default="peer")
    parser.add_argument("--json", action="store_true", help="print each sample's JSON as is")
    parser.add_argument(
        "--latest", action="store_true",
        help="query dcobserver/*/latest once (KEYEXPR defaults to it) and exit",
    )  # fmt: skip
    parser.add_argument("--count", type=int, default=0, help="exit after N samples (0: never)")
    parser.add_argument(
        "--timeout", type=float, default=0.0, help="exit after S seconds (0: never)"
    )


def _row(key: str, e: dict[str, Any]) -> str:
    def val(c: str, p: str) -> str:
        d = e.get(c) or {}
        v = d.get(p)
        q = (d.get("quality") or {}).get(p, "")
        mark = {"ok": " ", "held": "h", "unconfirmed": "?", "none": "-"}.get(q, " ")
        return f"{'-' if v is None else format(v, '.5g'):>10}{mark}"

    drive = key.split("/")[1] if key.count("/") >= 2 else key
    t = e.get("t_ns", 0) / 1e9
    cells = [val("field", "R"), val("field", "L"), val("armature", "R")]
    cells += [val("armature", "L"), val("armature", "K")]
    return f"{drive:<12} {t:>9.2f} " + " ".join(cells)


HEADER = (
    f"{'drive':<12} {'t (s)':>9} {'Rf ohm':>11} {'Lf H':>11} {'Ra ohm':>11} {'La H':>11} "
    f"{'K H':>11}    (h: held, ?: unconfirmed, -: none)"
)


def main(args: argparse.Namespace) -> int:
    import queue

    import zenoh

    from observer.cli import UserError
    from observer.config import ZenohConfig
    from observer.service.zenohpub import zenoh_config_json

    listen = args.listen or []
    connect = (
        args.connect if args.connect is not None else ([] if listen else ["tcp/127.0.0.1:7447"])
    )
    cfg = ZenohConfig(mode=args.mode, listen=listen, connect=connect)
    try:
        session = zenoh.open(zenoh.Config.from_json5(zenoh_config_json(cfg)))
    except Exception as exc:
        raise UserError(f"cannot open a Zenoh session: {exc}") from None
    if args.latest:
        try:
            return _query_latest(session, args)
        finally:
            session.close()
    samples: queue.Queue[tuple[str, bytes]] = queue.Queue(1000)

    def on_sample(sample: Any) -> None:  # zenoh thread: hand over, never block
        try:
            samples.put_nowait((str(sample.key_expr), sample.payload.to_bytes()))
        except queue.Full:
            pass

    sub = session.declare_subscriber(args.keyexpr, on_sample)
    via = ", ".join([*connect, *(f"listening on {e}" for e in listen)])
    print(f"subscribed to {args.keyexpr} via {via}", file=sys.stderr, flush=True)
    if not args.json:
        print(HEADER, flush=True)
    received = 0
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else None
    try:
        while args.count <= 0 or received < args.count:
            if deadline is not None and time.monotonic() >= deadline:
                break
            try:
                key, payload = samples.get(timeout=0.2)
            except queue.Empty:
                continue
            received += 1
            if args.json:
                print(payload.decode(errors="replace"), flush=True)
                continue
            try:
                print(_row(key, json.loads(payload)), flush=True)
            except (ValueError, TypeError, AttributeError):
                print(f"{key}: not an estimate: {payload[:80]!r}", flush=True)
    finally:
        sub.undeclare()
        session.close()
    return 0


def _query_latest(session: Any, args: Any) -> int:
    """Ask every daemon's queryable for its latest estimate; retry until one answers."""
    keyexpr = args.keyexpr if args.keyexpr != "dcobserver/*/estimate" else "dcobserver/*/latest"
    deadline = time.monotonic() + (args.timeout if args.timeout > 0 else 10.0)
    if not args.json:
        print(HEADER, flush=True)
    while time.monotonic() < deadline:
        answered = 0
        for reply in session.get(keyexpr, timeout=1.0):
            if reply.ok is None:
                continue
            answered += 1
            key, payload = str(reply.ok.key_expr), reply.ok.payload.to_bytes()
            print(payload.decode() if args.json else _row(key, json.loads(payload)), flush=True)
        if answered:
            return 0
        time.sleep(0.2)
    print(f"no answer to {keyexpr}", file=sys.stderr)
    return 1
