"""The daemon's pipeline: source -> ring buffer -> sliding-window observer -> Zenoh and MCAP.

Threads:

* **acquisition** reads the source and writes the ring buffer, nothing else,
  so a slow estimate never stalls acquisition (numba kernels release the GIL);
* **observer** waits for the data to reach the next window's end, estimates,
  publishes, queues the raw samples and results for the log, emits health and
  pings the systemd watchdog (so a hung estimator gets the service restarted);
* **mcap-log** (in :class:`observer.service.mcaplog.McapLog`) writes the file;
* zenoh's own threads.

Start order: log, Zenoh, observer, acquisition; :meth:`Daemon.stop` stops them
in reverse (acquisition, observer, Zenoh undeclared, log finished).
"""

from __future__ import annotations

import dataclasses
import importlib.metadata
import json
import logging
import os
import socket
import statistics
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from drivers import Source, SourceClosed, source_class
from observer.config import Config
from observer.service import sdnotify
from observer.service.circuit_worker import parallel_wanted
from observer.service.mcaplog import (
    CONFIG_METADATA,
    LOG_METADATA,
    TIME_BASE,
    McapLog,
    to_json,
)
from observer.service.ringbuffer import RingBuffer
from observer.service.window_observer import SlidingWindowObserver, WindowResult

log = logging.getLogger(__name__)


def make_source(config: Config, config_path: str, base_dir: Path) -> Source:
    """The configured source (``[source] kind`` + ``[source.options]``)."""
    cls = source_class(config.source.kind)
    return cls.from_config(config.source.options, source=config_path, base_dir=base_dir)


def log_metadata(
    config: Config, source: Source, config_path: str | None
) -> dict[str, dict[str, str]]:
    """The metadata records that say what made a log file: software, ids, configuration."""
    text = ""
    if config_path:
        try:
            text = Path(config_path).read_text(encoding="utf-8")
        except OSError as exc:
            text = f"# cannot read {config_path}: {exc}"
    return {
        LOG_METADATA: {
            "software": "dcobserver",
            "version": _version(),
            "drive_id": config.observer.drive_id,
            "motor_id": config.observer.motor_id,
            "source": source.name,
            "host": socket.gethostname(),
            "pid": str(os.getpid()),
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "time_base": TIME_BASE,
        },
        CONFIG_METADATA: {
            "path": str(Path(config_path).resolve()) if config_path else "",
            "toml": text,
            "settings_json": json.dumps(dataclasses.asdict(config), default=str),
        },
    }


def _version() -> str:
    """The installed dcobserver's version (the package metadata: no import of ``observer``)."""
    try:
        return importlib.metadata.version("dcobserver")
    except importlib.metadata.PackageNotFoundError:
        return "unknown (not installed)"


def _recording_metadata(config: Config, source: Source) -> dict[str, Any]:
    return {
        "generator": "dcobserver run",
        "drive_id": config.observer.drive_id,
        "motor_id": config.observer.motor_id,
        "source": source.name,
    }


class Daemon:
    """One running pipeline.

    Parameters
    ----------
    config : Config
    source : Source
    on_estimate : callable, optional
        Called in the observer thread with every estimate dict (keep it quick).
    sample_rate_hint_hz : float
        Sizes the ring buffer (``buffer_s`` seconds at this rate).
    config_path : str, optional
        The configuration file, whose text every log file carries.
    """

    def __init__(
        self,
        config: Config,
        source: Source,
        *,
        on_estimate: Callable[[dict[str, Any]], None] | None = None,
        sample_rate_hint_hz: float = 20_000.0,
        config_path: str | None = None,
    ) -> None:
        from observer.service.zenohconf import names
        from observer.service.zenohpub import ZenohPublisher

        self.config = config
        self.source = source
        self.drive_id = config.observer.drive_id
        self.motor_id = config.observer.motor_id
        #: Names every estimate and health message carries.
        self.ids = names(self.drive_id, self.motor_id)
        self.ring = RingBuffer(max(1024, int(config.observer.buffer_s * sample_rate_hint_hz)))
        self.observer = SlidingWindowObserver(
            self.ring, config.observer, chain=config.chain,
            parallel=parallel_wanted(config.observer.parallel_circuits),
        )  # fmt: skip
        self.zenoh = ZenohPublisher(config.zenoh, self.drive_id, self.motor_id)
        self.mcap = (
            McapLog(
                config.log,
                self.drive_id,
                self.motor_id,
                metadata=log_metadata(config, source, config_path),
                recording_metadata=_recording_metadata(config, source),
            )
            if config.log.dir
            else None
        )
        self.on_estimate = on_estimate
        self.latencies_ms: deque[float] = deque(maxlen=2000)
        self.source_ended = threading.Event()
        self.finished = threading.Event()
        self._stop = threading.Event()
        self._source_errors = 0
        self._last_source_error = ""
        self._started = time.monotonic()
        self._last_sample_wall = time.monotonic()
        self._last_written = 0
        self._prev_counts: Counter[str] = Counter()
        self._acq = threading.Thread(target=self._acquire, name="acquisition", daemon=True)
        self._obs = threading.Thread(target=self._observe, name="observer", daemon=True)
        self._watchdog_s = sdnotify.watchdog_interval_s()
        self._next_health = 0.0  # monotonic times (s) health and the watchdog ping are due
        self._next_ping = 0.0
        self.observer_error = ""

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        self.observer.start_worker()  # the armature's process, if wanted: it loads meanwhile
        if self.mcap is not None:
            self.mcap.start()
        self.zenoh.start()
        wait = self.config.zenoh.wait_for_subscriber_s
        if wait > 0:
            if self.zenoh.wait_for_subscriber(wait):
                log.info("zenoh: a subscriber is matched; starting the source")
            else:
                log.warning("zenoh: no subscriber matched within %g s; starting anyway", wait)
        self._obs.start()
        self._acq.start()

    def stop(self, timeout: float = 10.0) -> list[str]:
        """Stop in reverse order: source, observer, Zenoh, log (the MCAP file is finished).

        Returns the names of the threads still running after ``timeout`` seconds each
        (normally none). Such a thread may be inside native code (a numba kernel, a
        Zenoh call): the interpreter must not be finalized under it, see
        :func:`observer.commands.run.main`.
        """
        self._stop.set()
        self.ring.notify()
        self._acq.join(timeout)
        try:
            self.source.close()
        except Exception as exc:
            log.warning("closing the source: %s", exc)
        self._obs.join(timeout)
        self.observer.close()
        self.zenoh.close(timeout)
        if self.mcap is not None:
            self.mcap.close()
        threads = (self._acq, self._obs, *self.zenoh.threads())
        return [t.name for t in threads if t.is_alive()]

    # ------------------------------------------------------------------ acquisition

    def _acquire(self) -> None:
        backoff = 0.1
        while not self._stop.is_set():
            try:
                block = self.source.read(timeout=0.2)
            except SourceClosed:
                if not self._stop.is_set():
                    log.info("source ended")
                self.source_ended.set()
                self.ring.notify()
                return
            except Exception as exc:  # a pump thread never dies silently
                self._source_errors += 1
                self._last_source_error = str(exc)
                log.error("source error (retrying in %.1f s): %s", backoff, exc)
                self._stop.wait(backoff)
                backoff = min(backoff * 2, 5.0)
                continue
            backoff = 0.1
            if block is not None and len(block):
                self.ring.write(block)

    # ------------------------------------------------------------------ observer

    def _observe(self) -> None:
        hop = self.config.observer.hop_s
        self._next_health = time.monotonic() + self.config.observer.health_s
        self._next_ping = 0.0
        while not self._stop.is_set():
            try:
                due = self.observer.next_due_ns()
                if due is None:
                    self.ring.wait_for(1, timeout=min(hop, 0.2))
                else:
                    self.ring.wait_for_time(due, timeout=min(hop, 0.2))
                self._log_new_samples()
                for result in self.observer.process_ready(live=True):
                    self._emit(result)
                    self._log_new_samples()
                    # An observer slower than the data never leaves this loop: health
                    # and the watchdog must not wait for it to catch up.
                    self._periodic()
                    if self._stop.is_set():  # stop now, not after every window ready
                        break
            except Exception as exc:  # never die silently: count, log, go on
                self.observer.counts["observer_errors"] += 1
                self.observer_error = f"{type(exc).__name__}: {exc}"
                log.exception("observer loop error")
            self._periodic()
            if self.source_ended.is_set() and not self._more_ready():
                self._log_new_samples()
                self.emit_health(state="source_ended")
                self.finished.set()
                return
        self._log_new_samples()

    def _periodic(self) -> None:
        """Ping the watchdog and emit health when they are due."""
        now = time.monotonic()
        if self._watchdog_s is not None and now >= self._next_ping:
            sdnotify.watchdog()
            self._next_ping = now + self._watchdog_s
        if now >= self._next_health:
            self.emit_health()
            self._next_health = now + self.config.observer.health_s

    def _more_ready(self) -> bool:
        due = self.observer.next_due_ns()
        last = self.ring.last_t_ns
        return due is not None and last is not None and last >= due

    def _log_new_samples(self) -> None:
        while True:
            window = self.ring.read_new(max_samples=self.ring.capacity // 2)
            if window is None:
                return
            self._last_sample_wall = time.monotonic()
            if self.mcap is not None:
                wall = window.arrival_ns + (time.time_ns() - time.monotonic_ns())
                self.mcap.submit_samples(
                    window.t_ns, window.signals, arrival_wall_ns=wall, scales=window.scales
                )

    def _emit(self, result: WindowResult) -> None:
        if result.estimate is None:
            return
        estimate = {**self.ids, **result.estimate}
        payload = to_json(estimate)
        self.zenoh.publish("estimate", payload)
        self.latencies_ms.append((time.monotonic_ns() - result.arrival_ns) / 1e6)
        if self.mcap is not None:
            self.mcap.submit_json("/estimate", estimate)
        for event in result.events:
            self._emit_event(event)
        if self.on_estimate is not None:
            self.on_estimate(estimate)

    def _emit_event(self, event: dict[str, Any]) -> None:
        """A change or tachometer alarm: Zenoh ``event``, the MCAP ``/event`` topic, the log."""
        event = {**self.ids, **event}
        self.zenoh.publish("event", to_json(event))
        if self.mcap is not None:
            self.mcap.submit_json("/event", event)
        log.warning("event: %s", event["message"])

    # ------------------------------------------------------------------ health

    def health(self, state: str = "running") -> dict[str, Any]:
        ring = self.ring.stats()
        obs = self.observer.health()
        counts = Counter(self.observer.counts)
        recent = {k: v - self._prev_counts.get(k, 0) for k, v in counts.items()}
        recent = {k: v for k, v in recent.items() if v}
        self._prev_counts = counts
        flags: list[str] = []
        stalled = time.monotonic() - self._last_sample_wall
        if self.source_ended.is_set():
            flags.append("source_ended")
        elif stalled > self.config.observer.stall_s:
            flags.append("source_stalled")
        flags += sorted({f"window_{k}" for k in recent if k.startswith("skipped:")})
        if recent.get("late"):
            flags.append("observer_late")
        if ring["overruns"]:
            flags.append("ring_overrun")
        source_health = self.source.health()
        if self._source_errors or source_health.get("errors"):
            flags.append("source_errors")
        zenoh = self.zenoh.health()
        if zenoh["state"] == "unreachable":
            flags.append("zenoh_unreachable")
        log_health = self.mcap.health() if self.mcap is not None else {"state": "off"}
        if log_health.get("state") == "error":
            flags.append("log_error")
        latencies = list(self.latencies_ms)
        lat = {}
        if latencies:
            q = statistics.quantiles(latencies, n=100) if len(latencies) > 1 else latencies * 99
            lat = {"p50": q[49], "p99": q[98], "n": len(latencies)}
        return {
            **self.ids,
            "wall_time_ns": time.time_ns(),
            "uptime_s": time.monotonic() - self._started,
            "state": state,
            "flags": flags,
            "source": {
                **source_health,
                "thread_errors": self._source_errors,
                "last_thread_error": self._last_source_error,
                "seconds_since_sample": stalled,
            },
            "ring": ring,
            "observer": {**obs, "windows_recent": recent, "last_error": self.observer_error},
            "zenoh": zenoh,
            "log": log_health,
            "latency_ms": lat,
        }

    def emit_health(self, state: str = "running") -> dict[str, Any]:
        health = self.health(state)
        self.zenoh.publish("health", to_json(health))
        if self.mcap is not None:
            self.mcap.submit_json("/health", health, health["wall_time_ns"])
        if health["flags"]:
            log.info("health: %s", ", ".join(health["flags"]))
        return health


#: How long an offline replay waits for its circuit worker to load the kernels before it
#: starts (windows estimate both circuits here until it is ready).
WORKER_WAIT_S = 10.0


def run_offline(
    config: Config,
    source: Source,
    *,
    on_result: Callable[[WindowResult], None] | None = None,
    progress: Callable[[int], None] | None = None,
    sample_rate_hint_hz: float = 20_000.0,
    parallel: bool = False,
) -> SlidingWindowObserver:
    """Run the observer over a whole source in this thread (``dcobserver replay``).

    Same windows, seeds and warm starts as the live daemon, so the same
    estimates (when the live daemon kept up). ``progress`` gets the samples
    of each block read. ``parallel``: the armature's estimates in a second
    process (:mod:`.circuit_worker`; the same numbers), stopped at the end.
    """
    ring = RingBuffer(max(1024, int(config.observer.buffer_s * sample_rate_hint_hz)))
    observer = SlidingWindowObserver(ring, config.observer, chain=config.chain, parallel=parallel)
    try:
        observer.start_worker(wait_s=WORKER_WAIT_S)
        with source:
            for block in source:
                ring.write(block)
                for result in observer.process_ready(live=False):
                    if on_result is not None:
                        on_result(result)
                if progress is not None:
                    progress(len(block))
    finally:
        observer.close()
    return observer
