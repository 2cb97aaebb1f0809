"""The daemon's MCAP log: raw samples, estimates and health, with rotation, retention, metadata.

One time base: every message's ``log_time`` (and ``publish_time``) is
wall-clock Unix time in nanoseconds, what Foxglove and every MCAP tool
expect: for raw samples the time the block's first sample reached the
daemon, for estimates the time they were published, for health the time it
was taken. The data's own clock (the device's, or a replay's) is in the
payload: ``t0_ns`` (and ``period_ns``) of a sample block, ``t_ns`` and
``window`` of an estimate; health carries ``wall_time_ns``.

Raw samples go on :data:`~observer.recording.SAMPLES_TOPIC` as the compact
protobuf blocks of :mod:`observer.recording.sample_proto` (ADC counts with
their scale where the source knows them, float64 otherwise), so ``dcobserver
estimate``, ``dcobserver replay`` and the replay source read daemon logs and
reproduce the live numbers exactly. Estimates and health go on ``/estimate``
and ``/health``, confirmed changes and tachometer alarms on ``/event``
(``log_time``: when they were published), as JSON with a JSON schema each
(Foxglove plots them).

Each file describes itself in metadata records: :data:`LOG_METADATA`
(software, version, drive and motor ids, host, time base),
:data:`CONFIG_METADATA` (the configuration file and the settings in force),
:data:`CHANNELS_METADATA` (units and ADC scales) and the recording metadata
that :func:`observer.recording.read_mcap` returns.

Crash safety: a file is written under a hidden temporary name, locked while
open, and renamed when complete (:class:`observer.recording.AtomicFile`), so a
final name is always a valid, indexed file. The chunk in progress is closed
and flushed to the file every ``flush_s`` seconds, so a crash or power loss
loses about that much. At start the log thread recovers this daemon's files
a crash left under temporary names (:func:`recover_cut_logs`: rewritten by
:func:`recover`, read back whole, and only then the original deleted).

Retention (:mod:`observer.service.logfiles`): after each rotation and every
minute the oldest files of this drive go until the rest fit ``max_total_gb``
and ``max_age_days``; never the open file. Deletions are logged and counted.

Write errors (disk full, file too large, directory gone) never propagate:
they are counted, reported in :meth:`McapLog.health`, and a new file is tried
after ``retry_s``.
"""

from __future__ import annotations

import fcntl
import itertools
import json
import logging
import math
import os
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
from mcap.writer import CompressionType, Writer

from drivers.base import AdcScale
from observer.config import LogConfig
from observer.recording import (
    ADC_KEY,
    CHANNELS,
    MEANINGS,
    METADATA_NAME,
    PROTO_ENCODING,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    UNITS,
    AtomicFile,
    proto_schema_data,
    sample_block_proto,
)
from observer.recording import AdcScale as RecordingScale
from observer.service.logfiles import Retention, log_stem

log = logging.getLogger(__name__)

LOG_METADATA: Final = "dcobserver.log"
CONFIG_METADATA: Final = "dcobserver.config"
CHANNELS_METADATA: Final = "dcobserver.channels"
TIME_BASE: Final = (
    "log_time and publish_time: wall-clock Unix time (ns) when the daemon received the "
    "samples, published the estimate or took the health; data time (source clock) in the "
    "payload: /samples t0_ns + i*period_ns (+ t_residual_ns), /estimate t_ns and window"
)
_RETENTION_EVERY_S: Final = 60.0

ESTIMATE_TOPIC = "/estimate"
HEALTH_TOPIC = "/health"
EVENT_TOPIC = "/event"

_PARAM = {"type": ["number", "null"]}
_CIRCUIT_SCHEMA: dict[str, Any] = {
    "type": "object",
    "properties": {
        "R": {**_PARAM, "description": "Resistance (ohm)."},
        "L": {**_PARAM, "description": "Inductance (H)."},
        "K": {**_PARAM, "description": "EMF constant (V*s/(rad*A)); armature only."},
        "kphi": {
            **_PARAM,
            "description": "K times the window's mean field current: the EMF constant at the "
            "present field (V*s/rad), as a data sheet gives it; armature only.",
        },
        "kphi_std": {**_PARAM, "description": "One-sigma of kphi (V*s/rad)."},
        "if_mean": {**_PARAM, "description": "The window's mean field current (A)."},
        "rms": {**_PARAM, "description": "RMS current error of the window's fit (A)."},
        "std": {
            "type": "object",
            "description": "One-sigma of the tracked R, L, K (same units).",
            "additionalProperties": _PARAM,
        },
        "quality": {
            "type": "object",
            "description": "Per parameter: ok (this window updated the tracked value), held "
            "(the window is no evidence for it: carried forward), outlier (too far from the "
            "tracked value to update it), change (a change being confirmed: frozen), none "
            "(no evidence yet).",
            "additionalProperties": {"enum": ["ok", "held", "outlier", "change", "none"]},
        },
        "raw": {
            "type": "object",
            "description": "This window's own fit of R, L, K (for diagnosis and replay).",
            "additionalProperties": _PARAM,
        },
        "rel_std": {
            "type": "object",
            "description": "One-sigma relative uncertainty of this window's own fit.",
            "additionalProperties": _PARAM,
        },
        "rate_per_min": {
            "type": "object",
            "description": "Tracked relative rate of change of R per minute.",
            "additionalProperties": _PARAM,
        },
        "std_scale": {
            "type": "object",
            "description": "The factor on the windows' own variances the tracker learned from "
            "how far windows a window apart scatter (1: as the windows say).",
            "additionalProperties": _PARAM,
        },
    },
}
_WINDING_TEMPERATURE = {
    "type": "object",
    "properties": {
        "C": {"type": "number", "description": "Winding temperature (deg C) from the tracked R."},
        "std": {"type": "number", "description": "Its one-sigma (K)."},
    },
}
_EVENT_PROPERTIES: dict[str, Any] = {
    "drive_id": {"type": "string"},
    "kind": {"enum": ["change", "tachometer"]},
    "t_ns": {"type": "integer", "description": "End of the window that raised it (ns)."},
    "message": {"type": "string"},
    "parameter": {"type": "string", "description": "change: Rf, Lf, Ra, La or K."},
    "relative": {
        "type": "number",
        "description": "change: size (after/before - 1); tachometer: measured/EMF speed - 1.",
    },  # fmt: skip
    "relative_std": {"type": "number"},
    "before": {"type": "number"},
    "after": {"type": "number"},
    "t_change_ns": {"type": "integer", "description": "change: when it happened (ns)."},
    "state": {"enum": ["fault", "cleared"], "description": "tachometer"},
    "since_ns": {"type": "integer", "description": "tachometer: disagreement since (ns)."},
    "measured_rad_s": {"type": "number"},
    "emf_rad_s": {"type": "number"},
}
EVENT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "dcobserver.Event",
    "description": "A confirmed change of a parameter, or a tachometer alarm raised or cleared.",
    "type": "object",
    "properties": _EVENT_PROPERTIES,
    "required": ["kind", "t_ns", "message"],
}
ESTIMATE_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "dcobserver.Estimate",
    "description": "Winding parameters estimated over one sliding window.",
    "type": "object",
    "properties": {
        "drive_id": {"type": "string"},
        "index": {"type": "integer", "description": "Window number since the first sample."},
        "t_ns": {
            "type": "integer",
            "description": "Window end in data time (the source's clock, ns).",
        },
        "window": {
            "type": "array",
            "items": {"type": "integer"},
            "minItems": 2,
            "maxItems": 2,
            "description": "[t0, t1] (data time, ns): samples with t0 < t <= t1.",
        },
        "n_samples": {"type": "integer"},
        "elapsed_ms": {"type": "number", "description": "Estimation time (ms)."},
        "field": _CIRCUIT_SCHEMA,
        "armature": _CIRCUIT_SCHEMA,
        "temperature": {
            "type": "object",
            "description": "Winding temperatures from the tracked resistances (where a "
            "reference resistance is configured).",
            "properties": {"field": _WINDING_TEMPERATURE, "armature": _WINDING_TEMPERATURE},
        },
        "speed": {
            "type": "object",
            "description": "EMF speed from the tracked armature parameters beside the "
            "measured speed (flux-weighted window means, rad/s).",
            "properties": {
                "emf_rad_s": _PARAM,
                "std_rad_s": _PARAM,
                "measured_rad_s": _PARAM,
                "measured_std_rad_s": _PARAM,
                "tachometer": {"enum": ["ok", "fault", "none"]},
                "note": {"type": "string"},
            },
        },
        "events": {
            "type": "array",
            "description": "Events raised by this window (also on /event).",
            "items": {"type": "object", "properties": _EVENT_PROPERTIES},
        },
        "flags": {"type": "array", "items": {"type": "string"}},
    },
    "required": ["t_ns", "window"],
}
HEALTH_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "dcobserver.Health",
    "description": "Counters of the daemon: source, ring buffer, windows, outputs.",
    "type": "object",
    "properties": {
        "drive_id": {"type": "string"},
        "wall_time_ns": {"type": "integer", "description": "Wall-clock Unix time (ns)."},
        "uptime_s": {"type": "number"},
        "state": {"type": "string"},
        "flags": {"type": "array", "items": {"type": "string"}},
        "source": {"type": "object"},
        "ring": {"type": "object"},
        "observer": {"type": "object"},
        "zenoh": {"type": "object"},
        "log": {"type": "object"},
        "latency_ms": {"type": "object"},
    },
    "required": ["wall_time_ns", "state"],
}


_FILE_NUMBERS = itertools.count(1)  # per process, across McapLog instances (reloads)


def json_safe(value: Any) -> Any:
    """``value`` ready for strict JSON: NaN and infinities become null (JSON has neither),
    numpy scalars Python numbers, mapping keys strings."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, np.generic):
        return json_safe(value.item())
    return value


def to_json(obj: Any) -> bytes:
    """Compact JSON with non-finite floats as null."""
    return json.dumps(json_safe(obj), separators=(",", ":"), allow_nan=False).encode()


def _channels_metadata(scales: Mapping[str, AdcScale]) -> dict[str, str]:
    """Per channel: unit, meaning and ADC scale (if known), each value a JSON string."""
    out = {}
    for name in CHANNELS:
        entry: dict[str, Any] = {"unit": UNITS[name], "description": MEANINGS[name]}
        if name in scales:
            entry[ADC_KEY] = RecordingScale(*scales[name]).as_metadata()
        out[name] = json.dumps(entry)
    return out


class _File:
    """One open MCAP file with its channels and its metadata records.

    Written under a temporary name (:class:`observer.recording.AtomicFile`) and
    renamed to ``path`` by :meth:`finish` once complete, so a file under a
    final name is always a finished, indexed MCAP file. The temporary file is
    locked (``flock``) while open: a daemon starting beside a running one never
    mistakes the other's open file for one cut by a crash.
    """

    def __init__(
        self, path: Path, chunk_size: int, metadata: Mapping[str, Mapping[str, str]]
    ) -> None:
        self.path = path
        # overwrite=False: never replace a log, even one of the same second and process.
        self.out = AtomicFile(path, overwrite=False)
        self.stream: IO[bytes] = self.out.stream
        try:
            fcntl.flock(self.stream.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            self.writer = Writer(
                self.stream, chunk_size=chunk_size, compression=CompressionType.ZSTD
            )
            self.writer.start(profile="", library="dcobserver")
            ids = {}
            sid = self.writer.register_schema(
                SAMPLES_SCHEMA_NAME, PROTO_ENCODING, proto_schema_data()
            )
            ids[SAMPLES_TOPIC] = self.writer.register_channel(SAMPLES_TOPIC, PROTO_ENCODING, sid)
            for topic, schema in (
                (ESTIMATE_TOPIC, ESTIMATE_SCHEMA),
                (HEALTH_TOPIC, HEALTH_SCHEMA),
                (EVENT_TOPIC, EVENT_SCHEMA),
            ):
                sid = self.writer.register_schema(
                    schema["title"], "jsonschema", json.dumps(schema).encode()
                )
                ids[topic] = self.writer.register_channel(topic, "json", sid)
            for name, record in metadata.items():
                self.writer.add_metadata(name, dict(record))
            self.writer.flush()
            self.stream.flush()
        except BaseException:
            self.out.discard()
            raise
        self.channels = ids
        self.opened = time.monotonic()

    @property
    def temp_path(self) -> Path:
        """Where the bytes are until :meth:`finish`."""
        return self.out.temp_path

    def add(self, topic: str, log_time_ns: int, data: bytes) -> None:
        t = max(0, int(log_time_ns))
        self.writer.add_message(self.channels[topic], t, data, t)

    def flush(self) -> None:
        self.writer.flush()
        self.stream.flush()
        os.fsync(self.stream.fileno())

    @property
    def size(self) -> int:
        return self.stream.tell()

    def finish(self) -> Path:
        """Write the summary, make it durable and give the file its final name."""
        try:
            self.writer.finish()
            self.stream.flush()
            os.fsync(self.stream.fileno())
        except BaseException:
            self.out.leave()  # a full disk: what was written stays, for recovery at the next start
            raise
        return self.out.commit()

    def abandon(self) -> None:
        """Close after a write error, leaving the partial file for recovery at the next start."""
        self.out.leave()


class McapLog:
    """Writes the daemon's log in its own thread; producers never block.

    Parameters
    ----------
    config : LogConfig
        ``dir`` must be set.
    drive_id : str
        Part of the file names.
    motor_id : str
        Part of the file names when set (one daemon per motor of a drive).
    metadata : Mapping[str, Mapping[str, str]], optional
        Metadata records written at the start of every file besides the
        channels and recording records this class writes (the daemon gives
        :data:`LOG_METADATA` and :data:`CONFIG_METADATA`).
    recording_metadata : Mapping[str, Any], optional
        What :func:`observer.recording.read_mcap` shall return as the log's
        metadata (the ADC scales are added once known).
    queue_size : int
        Items waiting; beyond it items are dropped and counted.
    retry_s : float
        Pause before opening a new file after a write error.
    """

    def __init__(
        self,
        config: LogConfig,
        drive_id: str,
        motor_id: str = "",
        *,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        recording_metadata: Mapping[str, Any] | None = None,
        queue_size: int = 2000,
        retry_s: float = 5.0,
    ) -> None:
        self.config = config
        self.drive_id = drive_id
        self.dir = Path(config.dir)
        self.retry_s = retry_s
        self.metadata = dict(metadata or {})
        self.recording_metadata = dict(recording_metadata or {})
        self.stem = log_stem(config.prefix, drive_id, motor_id)
        self.retention = Retention(
            self.dir,
            self.stem,
            max_total_bytes=int(config.max_total_gb * 1e9),
            max_age_s=config.max_age_days * 86400.0,
        )
        self._queue: queue.Queue[tuple[str, int, Any] | None] = queue.Queue(queue_size)
        self._file: _File | None = None
        self._lock = threading.Lock()
        self._health: dict[str, Any] = {
            "file": "",
            "files": 0,
            "messages": 0,
            "bytes": 0,
            "errors": 0,
            "dropped": 0,
            "last_error": "",
            "state": "starting",
            "recovered_files": 0,
            "recovered_messages": 0,
        }
        self._next_try = 0.0
        self._last_flush = time.monotonic()
        self._next_retention = 0.0
        self._scales: Mapping[str, AdcScale] = {}
        self._thread = threading.Thread(target=self._run, name="mcap-log", daemon=True)
        self._seq = 0

    # ---------------------------------------------------------------- producers

    def start(self) -> None:
        self._thread.start()

    def submit_samples(
        self,
        t_ns: np.ndarray,
        signals: Mapping[str, np.ndarray],
        *,
        arrival_wall_ns: np.ndarray | None = None,
        scales: Mapping[str, AdcScale] | None = None,
    ) -> None:
        """Queue raw samples (split into ``block_s`` messages when written).

        ``arrival_wall_ns`` (wall-clock Unix ns per sample, when it reached the
        daemon) gives each message its ``log_time``; without it, now. Channels
        of ``scales`` are stored as counts where their values allow it exactly.
        """
        if arrival_wall_ns is None:
            arrival_wall_ns = np.full(len(t_ns), time.time_ns(), dtype=np.int64)
        payload = (t_ns, dict(signals), arrival_wall_ns, dict(scales or {}))
        self._put(("samples", int(arrival_wall_ns[0]) if len(t_ns) else 0, payload))

    def submit_json(self, topic: str, obj: Any, log_time_ns: int | None = None) -> None:
        """Queue a JSON message on ``/estimate``, ``/health`` or ``/event``.

        Its log time is wall clock, now unless given.
        """
        self._put((topic, time.time_ns() if log_time_ns is None else log_time_ns, obj))

    def _put(self, item: tuple[str, int, Any]) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            with self._lock:
                self._health["dropped"] += 1

    def health(self) -> dict[str, Any]:
        with self._lock:
            out = dict(self._health)
        out["retention"] = self.retention.health()
        return out

    def close(self, timeout: float = 10.0) -> None:
        """Write what is queued, finish the file (valid, indexed) and stop the thread."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join(timeout)
        elif self._file is not None:
            self._finish()

    # ---------------------------------------------------------------- writer thread

    def _set(self, **changes: Any) -> None:
        with self._lock:
            self._health.update(changes)

    def _error(self, exc: BaseException, doing: str) -> None:
        with self._lock:
            self._health["errors"] += 1
            self._health["last_error"] = f"{doing}: {exc}"
            self._health["state"] = "error"
        log.error("MCAP log: %s: %s (estimation goes on; retry in %g s)", doing, exc, self.retry_s)
        if self._file is not None:
            self._file.abandon()
            self._file = None
        self._next_try = time.monotonic() + self.retry_s

    def _file_metadata(self) -> dict[str, Mapping[str, str]]:
        recording = dict(self.recording_metadata)
        if self._scales:
            recording[ADC_KEY] = {
                c: RecordingScale(*s).as_metadata() for c, s in self._scales.items()
            }
        return {
            **self.metadata,
            CHANNELS_METADATA: _channels_metadata(self._scales),
            METADATA_NAME: {"json": json.dumps(recording)},
        }

    def _open(self) -> bool:
        if self._file is not None:
            return True
        if time.monotonic() < self._next_try:
            return False
        self._seq = next(_FILE_NUMBERS)
        stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
        name = f"{self.stem}-{stamp}-{os.getpid()}-{self._seq:04d}.mcap"
        try:
            self.dir.mkdir(parents=True, exist_ok=True)
            self._file = _File(
                self.dir / name, chunk_size=4 * 1024 * 1024, metadata=self._file_metadata()
            )
        except OSError as exc:
            self._error(exc, f"cannot open {self.dir / name}")
            return False
        with self._lock:
            self._health["file"] = str(self._file.path)
            self._health["files"] += 1
            self._health["state"] = "ok"
        log.info(
            "MCAP log: writing %s (as %s until it is complete)",
            self._file.path,
            self._file.temp_path.name,
        )
        self._enforce_retention()
        return True

    def _enforce_retention(self) -> None:
        self._next_retention = time.monotonic() + _RETENTION_EVERY_S
        keep = self._file.path if self._file is not None else None
        try:
            self.retention.enforce(keep=keep)
        except OSError as exc:  # never fatal: counted, logged, tried again later
            self._error(exc, "retention")

    def _finish(self) -> None:
        if self._file is None:
            return
        try:
            path = self._file.finish()
            log.info("MCAP log: finished %s", path)
        except OSError as exc:
            self._error(exc, f"cannot finish {self._file.path}")
        self._file = None
        self._enforce_retention()

    def _write(self, kind: str, log_time: int, payload: Any) -> None:
        if kind == "samples" and payload[3]:
            self._scales = payload[3]
        if not self._open():
            with self._lock:
                self._health["dropped"] += 1
            return
        assert self._file is not None
        try:
            if kind == "samples":
                self._write_samples(*payload)
            else:
                self._file.add(kind, log_time, to_json(payload))
                self._count()
        except (OSError, ValueError) as exc:
            self._error(exc, f"cannot write {self._file.path}")

    def _write_samples(
        self,
        t_ns: np.ndarray,
        signals: Mapping[str, np.ndarray],
        arrival_wall_ns: np.ndarray,
        scales: Mapping[str, AdcScale],
    ) -> None:
        assert self._file is not None
        # A channel the source does not provide is NaN in the ring buffer.
        present = {c: v for c, v in signals.items() if not np.isnan(v[0])}
        if not present or not len(t_ns):
            return
        step = self._block_samples(t_ns)
        block_scales = {c: RecordingScale(*s) for c, s in scales.items() if c in present}
        for start in range(0, len(t_ns), step):
            sl = slice(start, start + step)
            data = sample_block_proto(
                t_ns[sl], {c: v[sl] for c, v in present.items()}, block_scales
            )
            self._file.add(SAMPLES_TOPIC, int(arrival_wall_ns[start]), data)
            self._count()

    def _block_samples(self, t_ns: np.ndarray) -> int:
        if len(t_ns) < 2:
            return 1
        period = float(np.median(np.diff(t_ns)))
        return max(1, int(round(self.config.block_s * 1e9 / max(period, 1.0))))

    def _count(self) -> None:
        with self._lock:
            self._health["messages"] += 1

    def _maintain(self) -> None:
        """Flush every ``flush_s``; rotate by size or age; retention every minute."""
        if self._file is None:
            return
        now = time.monotonic()
        try:
            if now - self._last_flush >= self.config.flush_s:
                self._file.flush()
                self._last_flush = now
                self._set(bytes=self._file.size)
            if (
                self._file.size >= self.config.rotate_mb * 1e6
                or now - self._file.opened >= self.config.rotate_s
            ):
                log.info("MCAP log: rotating %s", self._file.path)
                self._finish()
        except OSError as exc:
            self._error(exc, f"cannot flush {self._file.path}")
        if now >= self._next_retention:
            self._enforce_retention()

    def _recover_leftovers(self) -> None:
        """Recover this daemon's logs that a crash left under their temporary names."""
        try:
            results = recover_cut_logs(self.dir, self.retention)
        except OSError as exc:
            self._error(exc, "cannot look for logs cut by a crash")
            return
        for result in results:
            with self._lock:
                if result.error:
                    self._health["errors"] += 1
                    self._health["last_error"] = result.error
                else:
                    self._health["recovered_files"] += 1
                    self._health["recovered_messages"] += result.messages

    def _run(self) -> None:
        self._recover_leftovers()
        while True:
            try:
                item = self._queue.get(timeout=min(0.2, self.config.flush_s))
            except queue.Empty:
                item = ()  # type: ignore[assignment]
            try:
                if item is None:
                    self._finish()
                    self._set(state="closed")
                    return
                if item:
                    self._write(*item)
                self._maintain()
            except Exception as exc:  # the log thread must never die silently
                self._error(exc, "unexpected error")


@dataclass(frozen=True)
class Recovered:
    """What became of one log file a crash left behind."""

    cut: Path
    recovered: Path | None
    messages: int = 0
    error: str = ""


def recover_cut_logs(folder: Path, retention: Retention) -> list[Recovered]:
    """Recover the logs a crash left in ``folder`` under their temporary names.

    Each such file of this daemon (its final name matches ``retention``'s), not
    locked by a live writer, is rewritten as a valid file under its final name
    (:func:`recover`); the result is opened with mcap's indexed reader and every
    message read back before the cut original is deleted. A file holding no
    complete message is deleted; one that cannot be recovered is left as it is
    and reported.
    """
    from observer.recording import RecordingError, final_path, is_temporary

    results = []
    try:
        entries = sorted(folder.iterdir())
    except FileNotFoundError:
        return []
    for cut in entries:
        if not is_temporary(cut) or not retention.owns(final_path(cut).name):
            continue
        final = final_path(cut)
        try:
            with open(cut, "rb") as probe:
                try:
                    fcntl.flock(probe.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    continue  # a live daemon is writing it
                if final.exists():  # recovered before, but the original was not yet deleted
                    n = _verified_messages(final)
                else:
                    n = recover(cut, final, overwrite=False)
                    if _verified_messages(final) != n:
                        raise RecordingError("the recovered file does not read back", path=final)
            cut.unlink()
        except RecordingError as exc:
            if "nothing to recover" in str(exc):
                cut.unlink(missing_ok=True)
                log.info("MCAP log: removed %s, cut by a crash before any data", cut.name)
                continue
            results.append(Recovered(cut, None, error=f"cannot recover {cut}: {exc}"))
            log.error("MCAP log: cannot recover %s (left as it is): %s", cut, exc)
            continue
        except OSError as exc:
            results.append(Recovered(cut, None, error=f"cannot recover {cut}: {exc}"))
            log.error("MCAP log: cannot recover %s (left as it is): %s", cut, exc)
            continue
        log.info("MCAP log: recovered %s (%d messages) from a log cut by a crash", final, n)
        results.append(Recovered(cut, final, n))
    return results


def _verified_messages(path: Path) -> int:
    """Messages in a finished file, read back whole by mcap's indexed reader with CRC checks."""
    from mcap.reader import make_reader

    from observer.recording import RecordingError

    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary()
            n = sum(1 for _ in reader.iter_messages(log_time_order=False))
    except Exception as exc:  # mcap raises its own errors, struct.error, zstd errors...
        raise RecordingError(f"does not read back: {exc}", path=path) from None
    if summary is None or summary.statistics is None or summary.statistics.message_count != n:
        raise RecordingError("its summary does not count its messages", path=path)
    return n


def recover(
    source: str | os.PathLike[str],
    destination: str | os.PathLike[str],
    *,
    overwrite: bool = True,
) -> int:
    """Rewrite a truncated or unfinished MCAP file as a valid, indexed one.

    Every schema, channel, message and metadata record before the cut is kept.
    ``destination`` appears only when complete (:mod:`observer.recording.atomic`).

    Parameters
    ----------
    source : str or os.PathLike
        The cut file; never modified.
    destination : str or os.PathLike
        Where to write.
    overwrite : bool
        Whether an existing ``destination`` may be replaced (``FileExistsError``
        otherwise).

    Returns
    -------
    int
        The number of messages written (at least 1).

    Raises
    ------
    observer.recording.RecordingError
        If ``source`` is not an MCAP file, or holds no complete message before
        its cut (nothing to recover; ``destination`` is then not written).
    OSError
        If ``destination`` cannot be written.
    """
    from mcap.records import Channel, Message, Metadata, Schema

    from observer.recording import AtomicFile, McapRecordStream, RecordingError

    src = os.fspath(source)
    try:
        size = os.path.getsize(src)
        stream = open(src, "rb")  # noqa: SIM115
    except OSError as exc:
        raise RecordingError(f"cannot read file: {exc.strerror or exc}", path=src) from None
    with stream:
        if stream.read(8) != b"\x89MCAP0\r\n":
            raise RecordingError("not an MCAP file (no MCAP magic bytes at the start)", path=src)
        stream.seek(0)
        with AtomicFile(destination, overwrite=overwrite) as out:
            writer = Writer(out.stream, compression=CompressionType.ZSTD)
            writer.start(library="dcobserver recover")
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}
            n = 0
            records = McapRecordStream(stream, size)
            for record in records:
                if isinstance(record, Schema) and record.id not in schemas:
                    schemas[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data
                    )
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = writer.register_channel(
                        record.topic,
                        record.message_encoding,
                        schemas.get(record.schema_id, 0),
                        dict(record.metadata),
                    )
                elif isinstance(record, Message) and record.channel_id in channels:
                    writer.add_message(
                        channels[record.channel_id],
                        record.log_time,
                        record.data,
                        record.publish_time,
                        record.sequence,
                    )
                    n += 1
                elif isinstance(record, Metadata):
                    writer.add_metadata(record.name, dict(record.metadata))
            if n == 0:
                raise RecordingError(
                    f"no complete message in its {size} bytes: nothing to recover", path=src
                )
            if records.cut_reason is not None:
                log.warning("%s: stops at the cut (%s)", src, records.cut_reason)
            writer.finish()
    return n
