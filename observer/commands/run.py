"""``dcobserver run``: the real-time observer daemon (what systemd starts)."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

log = logging.getLogger("dcobserver.run")

#: The demo configuration: a replay of the bundled recording, looping at real time.
DEMO_CONFIG = Path(__file__).resolve().parents[2] / "config" / "demo.toml"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", metavar="TOML", default=None,
        help=f"configuration file (default: the demo, {DEMO_CONFIG.name})",
    )  # fmt: skip
    parser.add_argument("--quiet-estimates", action="store_true", help="do not log every estimate")


def format_estimate(e: dict[str, Any]) -> str:
    """One log line per estimate: tracked values in engineering units with their quality
    (ok/held/outlier/change/none), e.g. ``armature: Ra=3.501 ohm (ok), La=20.1 mH (held)``,
    then the winding temperatures and the EMF speed."""
    from observer.commands.display import NAMES, UNITS, eng

    parts = [f"window {e.get('index')} t={e['t_ns'] / 1e9:.2f}s"]
    for circuit in ("field", "armature"):
        c = e.get(circuit)
        if not c:
            continue
        items = []
        for p in ("R", "L", "K"):
            if p in c:
                q = c.get("quality", {}).get(p, "?")
                items.append(f"{NAMES[(circuit, p)]}={eng(c[p], UNITS[p])} ({q})")
        parts.append(f"{circuit}: " + ", ".join(items))
    temps = [f"{c} {t['C']:.1f} C" for c, t in (e.get("temperature") or {}).items()]
    if temps:
        parts.append("T " + ", ".join(temps))
    emf = (e.get("speed") or {}).get("emf_rad_s")
    if emf is not None:
        parts.append(f"EMF speed {emf:.1f} rad/s")
    parts.append(f"{e.get('elapsed_ms', 0):.0f} ms")
    return " | ".join(parts)


def describe_log(log_config: Any, drive_id: str, motor_id: str = "") -> str:
    """One line saying where the MCAP log goes and how much of it is kept."""
    from observer.service.logfiles import log_stem

    if not log_config.dir:
        return "MCAP log: off ([log] dir is empty)"
    limits = []
    if log_config.max_total_gb:
        limits.append(f"at most {log_config.max_total_gb:g} GB")
    if log_config.max_age_days:
        limits.append(f"at most {log_config.max_age_days:g} days old")
    kept = " and ".join(limits) + ", oldest deleted first" if limits else "never deleted"
    return (
        f"MCAP log: {log_config.dir}/{log_stem(log_config.prefix, drive_id, motor_id)}-*.mcap "
        f"({kept}; "
        "open them in Foxglove)"
    )


def _load(path: str) -> tuple[Any, Any]:
    from observer.config import load_config
    from observer.service.daemon import make_source

    config: Any = load_config(path)
    source = make_source(config, path, Path(path).resolve().parent)
    return config, source


def main(args: argparse.Namespace) -> int:
    from observer.cli import UserError
    from observer.service import sdnotify
    from observer.service.daemon import Daemon
    from observer.service.window_observer import warm_up_kernels

    path = args.config or str(DEMO_CONFIG)
    if args.config is None and not DEMO_CONFIG.is_file():
        raise UserError(f"no --config given and the demo config {DEMO_CONFIG} is missing")
    try:
        config, source = _load(path)
    except Exception as exc:
        from drivers import SourceError

        if isinstance(exc, SourceError):
            raise UserError(f"{path}: {exc}") from None
        raise
    log.info("%s", describe_log(config.log, config.observer.drive_id, config.observer.motor_id))
    sdnotify.status("compiling numba kernels")
    seconds = warm_up_kernels()
    log.info("numba kernels ready in %.1f s", seconds)

    wake = threading.Event()
    requests: list[str] = []

    def on_signal(signum: int, _frame: object) -> None:
        requests.append("reload" if signum == signal.SIGHUP else "stop")
        wake.set()

    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, on_signal)

    def on_estimate(e: dict[str, Any]) -> None:
        if not args.quiet_estimates:
            log.info("%s", format_estimate(e))

    def start(cfg: Any, src: Any) -> Daemon:
        d = Daemon(cfg, src, on_estimate=on_estimate, config_path=path)
        d.start()
        return d

    daemon = start(config, source)
    sdnotify.ready(f"observing drive {config.observer.drive_id}")
    log.info("dcobserver running: drive %s, config %s", config.observer.drive_id, path)
    while True:
        wake.wait(0.5)
        wake.clear()
        while requests:
            request = requests.pop(0)
            if request == "stop":
                log.info("stopping (signal)")
                sdnotify.stopping()
                return _stopped(daemon)
            sdnotify.reloading()
            try:
                new_config, new_source = _load(path)
            except Exception as exc:
                log.error("reload failed, keeping the running configuration: %s", exc)
                sdnotify.ready("reload failed; running the previous configuration")
                continue
            log.info("reloading %s", path)
            stuck = daemon.stop()
            if stuck:
                log.warning("reload: threads %s of the old pipeline still run", ", ".join(stuck))
            daemon = start(new_config, new_source)
            sdnotify.ready(f"reloaded; observing drive {new_config.observer.drive_id}")
        if daemon.finished.is_set():
            log.info("source ended; stopping")
            sdnotify.stopping()
            return _stopped(daemon)


def _stopped(daemon: Any) -> int:
    """Stop the pipeline; exit status 0.

    A thread that did not end in time may be inside native code (a numba kernel,
    a Zenoh call). Finalizing the interpreter under it makes CPython end that thread
    with pthread_exit, whose unwinding through Rust frames aborts the process
    ("FATAL: exception not rethrown", status -6): with the log file finished and
    Zenoh closed, the process then ends at once instead.
    """
    stuck = daemon.stop()
    if not stuck:
        return 0
    log.warning("threads %s did not stop in time; exiting without waiting", ", ".join(stuck))
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(0)
