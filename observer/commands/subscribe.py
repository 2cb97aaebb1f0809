"""``dcobserver subscribe``: live estimates of any drive and motor, over Zenoh.

Two views: a **table** with one row per motor, redrawn in place (the default
on a terminal; ``dcobserver subscribe 'dcobserver/**'`` through a router shows
a whole fleet), and **lines**, one per message received (the default when
piped, and ``--json`` prints each message as it came).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TextIO

from observer.commands.display import ESTIMATE_UNITS, K_EXPLAINED, UNITS, eng
from observer.service.zenohconf import zenoh_error

if TYPE_CHECKING:
    from observer.config import ZenohLinkConfig

DEFAULT_KEYEXPR = "dcobserver/**/estimate"
DEFAULT_CONNECT = "tcp/127.0.0.1:7447"

#: Parameter quality, worst last (the quality column shows the worst of a motor's values).
#: ("change", "outlier": the tracker's, issue 11; "unconfirmed": the window fits' before it.)
QUALITY_ORDER = ("ok", "change", "outlier", "unconfirmed", "held", "none")
QUALITY_MARK = {
    "ok": " ", "change": "c", "outlier": "o", "unconfirmed": "?", "held": "h", "none": "-",
}  # fmt: skip
LEGEND = (
    "h: held, ?: unconfirmed, c: change being confirmed, o: outlier, -: none; "
    "±%: relative std of the value; speeds rad/s, !: tachometer fault, n: no speed channel"
)
#: What K is; the lines view shows kPhi at the window's mean field current beside it.
K_NOTE = K_EXPLAINED.format(at=" at the window's mean field current")
#: (column title, circuit, parameter) of the values shown (each cell with its unit).
VALUES = (
    ("Rf", "field", "R"),
    ("Lf", "field", "L"),
    ("Ra", "armature", "R"),
    ("La", "armature", "L"),
    ("K", "armature", "K"),
)
#: Width of a value with its unit (``-123.45 mohm``), then of its relative std (%).
CELL = 12
REL = 6
#: Each value's column title: its name over the value, ``±%`` over its relative std.
_TITLES = tuple(f"{title:>{CELL}}  {'±%':>{REL}}" for title, _c, _p in VALUES)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "keyexpr", nargs="?", default=DEFAULT_KEYEXPR, metavar="KEYEXPR",
        help="Zenoh key expression; 'dcobserver/**' adds health (and events) to the table",
    )  # fmt: skip
    parser.add_argument(
        "--config", metavar="TOML", default=None,
        help="a file with a [zenoh] table: endpoints, [zenoh.tls], [zenoh.auth] "
        "(config/fleet/control-room.toml)",
    )  # fmt: skip
    parser.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help=f"endpoint of a daemon or router, repeatable; without it the --config file's, "
        f"else {DEFAULT_CONNECT} (unless --listen is given)",
    )  # fmt: skip
    parser.add_argument(
        "--listen", action="append", default=None, metavar="ENDPOINT",
        help="listen here for daemons that connect to us (repeatable)",
    )  # fmt: skip
    parser.add_argument(
        "--mode", choices=("peer", "client"), default="peer",
        help="Zenoh role: 'peer' talks to daemons directly (and to other peers); 'client' "
        "only to the router or daemon given by --connect, and fails at once if none answers",
    )  # fmt: skip
    parser.add_argument(
        "--view", choices=("auto", "table", "lines"), default="auto",
        help="table: one row per motor, redrawn; lines: one line per message; "
        "auto: table on a terminal, else lines",
    )  # fmt: skip
    parser.add_argument(
        "--json", action="store_true",
        help="print each message's JSON as it came (an estimate's with a 'units' map added)",
    )  # fmt: skip
    parser.add_argument(
        "--refresh", type=float, default=1.0, metavar="S", help="table redraw period (s)"
    )
    parser.add_argument(
        "--latest", action="store_true",
        help="query dcobserver/**/latest once (KEYEXPR defaults to it) and exit",
    )  # fmt: skip
    parser.add_argument("--count", type=int, default=0, help="exit after N messages (0: never)")
    parser.add_argument(
        "--timeout", type=float, default=0.0, help="exit after S seconds (0: never)"
    )
    parser.add_argument(
        "--warn-after", type=float, default=3.0, metavar="S",
        help="warn if no daemon or router has answered a --connect endpoint after S seconds",
    )  # fmt: skip


def check_keyexpr(keyexpr: str, what: str = "KEYEXPR") -> None:
    """A one-line error for an invalid Zenoh key expression (``a//b``, ``/x``, ``a/**/**``)."""
    import zenoh

    from observer.cli import UserError

    try:
        zenoh.KeyExpr(keyexpr)
    except Exception as exc:  # zenoh.ZError
        problem = zenoh_error(exc)
        raise UserError(f"{what} {keyexpr!r} is not a valid key expression: {problem}") from None


# ---------------------------------------------------------------------------- formatting


def _value(e: dict[str, Any], circuit: str, param: str) -> str:
    """One cell: the tracked value in engineering units (``20.012 mH``), its quality mark
    and its relative std (%)."""
    c = e.get(circuit) or {}
    value = c.get(param)
    if not isinstance(value, int | float) or isinstance(value, bool):
        return f"{'-':>{CELL}}  {'':>{REL}}"
    mark = QUALITY_MARK.get((c.get("quality") or {}).get(param, ""), " ")
    std = (c.get("std") or {}).get(param)
    rel = ""
    if isinstance(std, int | float) and value and math.isfinite(std):
        percent = 100 * std / abs(value)
        rel = f"{percent:.2f}" if percent < 100 else f"{percent:.3g}"
    return f"{eng(value, UNITS[param], 5):>{CELL}} {mark}{rel:>{REL}}"


def _speeds(e: dict[str, Any]) -> str:
    """EMF speed and measured speed (rad/s), then ``!`` a tachometer fault, ``n`` no channel."""
    speed = e.get("speed") or {}
    emf, measured = speed.get("emf_rad_s"), speed.get("measured_rad_s")
    mark = {"fault": "!", "none": "n"}.get(str(speed.get("tachometer", "")), " ")
    emf_text = f"{emf:.1f}" if isinstance(emf, int | float) else "-"
    measured_text = f"{measured:.1f}" if isinstance(measured, int | float) else "-"
    return f"{emf_text:>7} {measured_text:>7}{mark}"


def _temperature(e: dict[str, Any], circuit: str) -> str:
    """A winding's temperature (degC) when the estimate carries one, else '-'.

    The tracker (issue 11) publishes ``temperature: {field: {C, std}, armature: {C, std}}``
    where a reference resistance is configured.
    """
    t = ((e.get("temperature") or {}).get(circuit) or {}).get("C")
    return "-" if not isinstance(t, int | float) else f"{t:.1f}"


def quality(e: dict[str, Any]) -> str:
    """The worst quality of the estimate's values (``ok`` when all are)."""
    worst = 0
    for _title, circuit, param in VALUES:
        q = ((e.get(circuit) or {}).get("quality") or {}).get(param)
        if q in QUALITY_ORDER:
            worst = max(worst, QUALITY_ORDER.index(q))
    return QUALITY_ORDER[worst] if any(e.get(c) for c in ("field", "armature")) else "-"


def names_of(key_expr: str, message: dict[str, Any]) -> tuple[str, str, str]:
    """``(drive, motor, leaf)``: the message's own names, else the key's."""
    from observer.service.zenohconf import parse_key

    drive, motor, leaf = parse_key(key_expr)
    drive = str(message.get("drive_id") or drive or key_expr)
    motor = str(message.get("motor_id") or motor or "-")
    return drive, motor, leaf


LINE_HEADER = (
    f"{'drive':<12} {'motor':<8} {'t (s)':>9} "
    + " ".join(_TITLES)
    + f" {'Tf C':>6} {'Ta C':>6} {'w_emf':>7} {'w_meas':>8}    ({LEGEND}; {K_NOTE})"
)


def format_line(key_expr: str, message: dict[str, Any]) -> str:
    """One line for one message: an estimate's values, or a health or other leaf in brief."""
    drive, motor, leaf = names_of(key_expr, message)
    head = f"{drive:<12} {motor:<8}"
    if leaf == "health":
        return f"{head} health: {', '.join(message.get('flags') or []) or 'ok'}"
    if leaf == "event":
        return f"{head} {message.get('t_ns', 0) / 1e9:>9.2f} EVENT {message.get('message', '')}"
    if leaf not in ("estimate", "latest"):
        return f"{head} {leaf}: {json.dumps(message)[:100]}"
    t = message.get("t_ns", 0) / 1e9
    cells = " ".join(_value(message, c, p) for _title, c, p in VALUES)
    temps = f"{_temperature(message, 'field'):>6} {_temperature(message, 'armature'):>6}"
    return f"{head} {t:>9.2f} {cells} {temps} {_speeds(message)} {_kphi(message)}"


def _kphi(e: dict[str, Any]) -> str:
    """``kPhi 1.2964 V*s/rad``: K at the window's field current (the data-sheet figure)."""
    kphi = (e.get("armature") or {}).get("kphi")
    if not isinstance(kphi, int | float) or isinstance(kphi, bool):
        return "kPhi -"
    return f"kPhi {eng(kphi, 'V*s/rad', 5)}"


@dataclass
class _Motor:
    estimate: dict[str, Any] = field(default_factory=dict)
    received: float | None = None
    health: str = "-"
    event: str = ""


class FleetTable:
    """The latest estimate and health of every motor heard from, one row each."""

    HEADER = (
        f"{'drive':<12} {'motor':<8} "
        + " ".join(_TITLES)
        + f" {'Tf C':>6} {'Ta C':>6} {'w_emf':>7} {'w_meas':>8} {'quality':<11} {'age s':>6}"
        + "  health"
    )

    def __init__(self) -> None:
        self.motors: dict[tuple[str, str], _Motor] = {}

    def update(self, key_expr: str, message: dict[str, Any], now: float) -> None:
        drive, motor, leaf = names_of(key_expr, message)
        row = self.motors.setdefault((drive, motor), _Motor())
        if leaf == "health":
            row.health = ", ".join(message.get("flags") or []) or "ok"
        elif leaf in ("estimate", "latest"):
            row.estimate = message
            row.received = now
        elif leaf == "event":  # the tracker's change and tachometer events (issue 11)
            row.event = str(message.get("message") or json.dumps(message))[:80]

    def render(self, now: float) -> list[str]:
        lines = [self.HEADER]
        for (drive, motor), row in sorted(self.motors.items()):
            e = row.estimate
            cells = " ".join(_value(e, c, p) for _title, c, p in VALUES)
            temps = f"{_temperature(e, 'field'):>6} {_temperature(e, 'armature'):>6}"
            age = "-" if row.received is None else f"{now - row.received:.1f}"
            status = row.health + (f"; last event: {row.event}" if row.event else "")
            lines.append(
                f"{drive:<12} {motor:<8} {cells} {temps} {_speeds(e)} {quality(e):<11} "
                f"{age:>6}  {status}"
            )
        lines.append(f"({LEGEND}; age: seconds since the last estimate arrived; {K_NOTE})")
        return lines


def _draw(out: TextIO, lines: list[str], in_place: bool) -> None:
    # On a terminal: home the cursor and clear below, so the table stays in one place.
    text = "\n".join(lines) + "\n"
    out.write(("\x1b[H\x1b[J" + text) if in_place else (text + "\n"))
    out.flush()


# ---------------------------------------------------------------------------- session


def session_link(
    args: argparse.Namespace,
    *,
    default_listen: Sequence[str] = (),
    default_connect: Sequence[str] = (DEFAULT_CONNECT,),
) -> ZenohLinkConfig:
    """The session's endpoints and security: ``args.config``'s ``[zenoh]`` table, its
    endpoints overridden by ``args.listen``/``args.connect``, else the defaults (``router``
    uses it too)."""
    from observer.cli import UserError
    from observer.config import ZenohFileConfig, ZenohLinkConfig, load_config
    from observer.service.zenohconf import with_endpoints

    link = load_config(args.config, ZenohFileConfig).zenoh if args.config else ZenohLinkConfig()
    try:
        return with_endpoints(
            link, args.listen, args.connect,
            default_listen=default_listen, default_connect=default_connect,
        )  # fmt: skip
    except ValueError as exc:
        raise UserError(str(exc)) from None


def main(args: argparse.Namespace) -> int:
    import queue

    import zenoh

    from observer.cli import UserError
    from observer.service.zenohconf import session_json

    check_keyexpr(args.keyexpr)
    times = (args.timeout, args.warn_after, args.refresh)
    if (
        args.count < 0
        or not (math.isfinite(sum(times)) and args.timeout >= 0)
        or not (args.warn_after > 0 and args.refresh > 0)
    ):
        raise UserError(
            "--count and --timeout must be >= 0, --warn-after and --refresh > 0 (finite)"
        )
    link = session_link(args)
    try:
        session = zenoh.open(zenoh.Config.from_json5(session_json(link, args.mode)))
    except Exception as exc:  # zenoh.ZError: a bad endpoint, a port in use, no router
        raise UserError(f"cannot open a Zenoh session: {zenoh_error(exc)}") from None
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
    via = ", ".join([*link.connect, *(f"listening on {e}" for e in link.listen)])
    print(f"subscribed to {args.keyexpr} via {via}", file=sys.stderr, flush=True)
    view = args.view
    if view == "auto":
        view = "table" if sys.stdout.isatty() and not args.json else "lines"
    table = FleetTable() if view == "table" and not args.json else None
    if table is None and not args.json:
        print(LINE_HEADER, flush=True)
    received = 0
    now = started = time.monotonic()
    deadline = now + args.timeout if args.timeout > 0 else None
    warned = not link.connect
    next_draw = now
    changed = True  # piped: draw only when something arrived (a terminal: every period, for age)
    try:
        while args.count <= 0 or received < args.count:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if not warned and now - started >= args.warn_after:
                warned = True
                if not received and not _connected(session):
                    print(
                        f"dcobserver subscribe: warning: nothing answers at "
                        f"{', '.join(link.connect)} after {args.warn_after:g} s (no daemon or "
                        "router there?); still trying",
                        file=sys.stderr, flush=True,
                    )  # fmt: skip
            if table is not None and now >= next_draw and (changed or sys.stdout.isatty()):
                _draw(sys.stdout, table.render(now), in_place=sys.stdout.isatty())
                next_draw = now + args.refresh
                changed = False
            try:
                key, payload = samples.get(timeout=0.2)
            except queue.Empty:
                continue
            received += 1
            if args.json:
                print(_with_units(key, payload), flush=True)
                continue
            try:
                message = json.loads(payload)
                if not isinstance(message, dict):
                    raise TypeError("not an object")
            except (ValueError, TypeError):
                if table is None:
                    print(f"{key}: not a dcobserver message: {payload[:80]!r}", flush=True)
                continue
            if table is not None:
                table.update(key, message, time.monotonic())
                changed = True
            else:
                print(format_line(key, message), flush=True)
    finally:
        if table is not None:
            _draw(sys.stdout, table.render(time.monotonic()), in_place=sys.stdout.isatty())
        sub.undeclare()
        session.close()
    return 0


def _with_units(key: str, payload: bytes) -> str:
    """A message's JSON as it came; an estimate's with a ``units`` map added (SI base units)."""
    text = payload.decode(errors="replace")
    if not key.endswith(("/estimate", "/latest")):
        return text
    try:
        message = json.loads(text)
    except ValueError:
        return text
    if not isinstance(message, dict) or "units" in message:
        return text
    return json.dumps({**message, "units": ESTIMATE_UNITS}, separators=(",", ":"))


def _connected(session: Any) -> bool:
    """Whether any Zenoh peer or router is connected to this session."""
    info = session.info
    return bool(list(info.peers_zid()) or list(info.routers_zid()))


def _query_latest(session: Any, args: Any) -> int:
    """Ask every daemon's queryable for its latest estimate; retry until one answers."""
    keyexpr = args.keyexpr if args.keyexpr != DEFAULT_KEYEXPR else "dcobserver/**/latest"
    deadline = time.monotonic() + (args.timeout if args.timeout > 0 else 10.0)
    if not args.json:
        print(LINE_HEADER, flush=True)
    while time.monotonic() < deadline:
        answered = 0
        for reply in session.get(keyexpr, timeout=1.0):
            if reply.ok is None:
                continue
            answered += 1
            key, payload = str(reply.ok.key_expr), reply.ok.payload.to_bytes()
            print(_with_units(key, payload) if args.json else format_line(key, json.loads(payload)))
        if answered:
            sys.stdout.flush()
            return 0
        time.sleep(0.2)
    print(f"no answer to {keyexpr}", file=sys.stderr)
    return 1
