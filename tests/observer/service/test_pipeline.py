"""The daemon's threads in-process: a source that stops, source errors, MCAP rotation/recover."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from drivers.base import SampleBlock, Source, SourceClosed
from observer.config import Config, LogConfig, ObserverConfig, ZenohConfig
from observer.recording import read_recording
from observer.service.daemon import Daemon
from observer.service.mcaplog import McapLog, recover
from replay.source import iter_mcap_blocks

OBS = ObserverConfig(
    drive_id="t", window_s=1.0, hop_s=0.25, cold_particles=20, cold_iterations=10,
    warm_particles=10, warm_iterations=8, health_s=0.2, stall_s=0.3, buffer_s=4.0,
)  # fmt: skip


class ScriptedSource(Source):
    """Blocks from a recording, then silence (``stop_after`` blocks) or errors."""

    name = "scripted"

    def __init__(self, rec, stop_after, fail_every=0):
        super().__init__()
        self.t_ns = np.rint(rec.t * 1e9).astype(np.int64)
        self.rec = rec
        self.i = 0
        self.n = 100  # 0.05 s at 2 kHz
        self.stop_after = stop_after
        self.fail_every = fail_every
        self.calls = 0
        self.silent = threading.Event()

    def _read_block(self, timeout):
        self.calls += 1
        if self.fail_every and self.calls % self.fail_every == 0:
            raise OSError("device not responding")
        if self.i >= self.stop_after:
            self.silent.set()
            time.sleep(min(timeout or 0.05, 0.05))  # a device that sends nothing
            return None
        sl = slice(self.i * self.n, (self.i + 1) * self.n)
        self.i += 1
        if sl.start >= self.rec.n_samples:
            raise SourceClosed("end")
        return SampleBlock(self.t_ns[sl], {c: self.rec[c][sl] for c in self.rec.channels})


def _wait(predicate, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


def test_source_that_stops_is_flagged_and_the_daemon_keeps_running(p12_recording):
    config = Config(observer=OBS, zenoh=ZenohConfig(enabled=False))
    source = ScriptedSource(p12_recording, stop_after=60)  # 3 s of data, then silence
    estimates = []
    daemon = Daemon(config, source, on_estimate=estimates.append)
    daemon.start()
    try:
        assert _wait(lambda: source.silent.is_set() and len(estimates) >= 8)
        assert _wait(lambda: "source_stalled" in daemon.health()["flags"])
        assert daemon._obs.is_alive() and daemon._acq.is_alive()
        assert [e["index"] for e in estimates] == list(range(len(estimates)))
    finally:
        daemon.stop()
    assert not daemon._obs.is_alive() and not daemon._acq.is_alive()


def test_source_errors_are_counted_and_acquisition_goes_on(p12_recording):
    config = Config(observer=OBS, zenoh=ZenohConfig(enabled=False))
    source = ScriptedSource(p12_recording, stop_after=10_000, fail_every=7)
    estimates = []
    daemon = Daemon(config, source, on_estimate=estimates.append)
    daemon.start()
    try:
        assert _wait(lambda: len(estimates) >= 4)
        health = daemon.health()
        assert health["source"]["thread_errors"] >= 1
        assert "device not responding" in health["source"]["last_thread_error"]
        assert "source_errors" in health["flags"]
    finally:
        daemon.stop()


def test_log_rotates_by_size_and_every_file_is_valid(tmp_path, p12_recording):
    cfg = LogConfig(dir=str(tmp_path), rotate_mb=0.05, flush_s=0.05, block_s=0.1)
    log = McapLog(cfg, "rot")
    log.start()
    t_ns = np.rint(p12_recording.t * 1e9).astype(np.int64)
    for i in range(0, 8000, 200):
        sl = slice(i, i + 200)
        log.submit_samples(t_ns[sl], {c: p12_recording[c][sl] for c in p12_recording.channels})
        log.submit_json("/health", {"state": "running", "wall_time_ns": 1})
        if i % 2000 == 0:
            assert _wait(lambda: log._queue.empty(), 10)  # let flushes and rotations happen
    log.close()
    files = sorted(tmp_path.glob("*.mcap"))
    assert len(files) >= 2 and log.health()["files"] == len(files)
    total = 0
    for f in files:
        with open(f, "rb") as fh:
            assert make_reader(fh).get_summary() is not None
        total += sum(len(b) for b in iter_mcap_blocks(f))  # a file may hold health only
    assert total == 8000 and log.health()["dropped"] == 0


def test_recover_rewrites_a_cut_file(tmp_path, p12_recording):
    cfg = LogConfig(dir=str(tmp_path), flush_s=0.05)
    log = McapLog(cfg, "cut")
    log.start()
    t_ns = np.rint(p12_recording.t * 1e9).astype(np.int64)
    for i in range(0, 4000, 200):
        sl = slice(i, i + 200)
        before = log.health()["bytes"]
        log.submit_samples(t_ns[sl], {"ia": p12_recording["ia"][sl]})
        assert _wait(lambda b=before: log.health()["bytes"] > b, 10)  # flushed as a chunk
    log.close()
    (path,) = tmp_path.glob("*.mcap")
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    n = recover(cut, tmp_path / "fixed.mcap")
    assert n > 0
    with open(tmp_path / "fixed.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None and summary.statistics.message_count == n
    assert read_recording(tmp_path / "fixed.mcap").n_samples == read_recording(cut).n_samples


def test_recover_rejects_a_non_mcap_file(tmp_path):
    from observer.recording import RecordingError

    bad = tmp_path / "x.mcap"
    bad.write_bytes(b"hello")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        recover(bad, tmp_path / "y.mcap")
