"""The armature estimated in a second process (parallel_circuits): the same numbers, a
worker that dies replaced by this process, no process left behind."""

from __future__ import annotations

import dataclasses
import logging
import os
import signal

import numpy as np
import pytest

from drivers.base import SampleBlock
from observer.config import Config, LogConfig, ObserverConfig, QualityConfig, ZenohConfig
from observer.estimation.motor import P12
from observer.service.circuit_worker import parallel_wanted
from observer.service.daemon import Daemon
from observer.service.ringbuffer import RingBuffer
from observer.service.window_observer import SlidingWindowObserver
from observer.simulation.converter import PRESETS
from observer.simulation.simulate import simulate
from tests.peers import free_port

CONFIG = ObserverConfig(
    window_s=1.0, hop_s=0.25, cold_particles=30, cold_iterations=20, warm_particles=16,
    warm_iterations=12, buffer_s=4.0, quality=QualityConfig(L=0.10),
)  # fmt: skip

#: A worker's first start on a cold numba cache compiles every kernel: give it time.
READY_S = 600.0


@pytest.fixture(scope="module")
def converter_recording():
    """6 s of the converter-fed P-12 (thyristor bridges, filters, 12-bit ADC), 2 kHz."""
    return simulate(
        P12, duration_s=6.0, sample_rate_hz=2000.0, seed=11, drive=PRESETS["realistic"],
        drive_name="realistic",
    )  # fmt: skip


def _blocks(rec, block_s=0.1):
    t_ns = np.rint(rec.t * 1e9).astype(np.int64)
    n = int(round(block_s / rec.dt))
    for i in range(0, rec.n_samples, n):
        yield SampleBlock(t_ns[i : i + n], {c: rec.signals[c][i : i + n] for c in rec.channels})


def _estimates(rec, parallel, on_window=None):
    """Every window's published estimate (without its timing) and the observer."""
    ring = RingBuffer(20_000)
    obs = SlidingWindowObserver(ring, CONFIG, parallel=parallel)
    if parallel:
        assert obs.start_worker(wait_s=READY_S)
    out = []
    try:
        for block in _blocks(rec):
            ring.write(block)
            for result in obs.process_ready():
                if result.estimate is not None:
                    out.append({k: v for k, v in result.estimate.items() if k != "elapsed_ms"})
                if on_window is not None:
                    on_window(obs, result)
    finally:
        health = obs.health()["parallel"]
        obs.close()
    return out, obs, health


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # A zombie is gone but for its exit status (the observer reaps it).
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split(") ", 1)[1][0] != "Z"


@pytest.mark.slow
@pytest.mark.slow
def test_the_armature_in_a_second_process_gives_the_very_numbers_of_one_process(
    converter_recording,
):
    serial, _, _ = _estimates(converter_recording, parallel=False)
    pids = []
    parallel, obs, health = _estimates(
        converter_recording, parallel=True,
        on_window=lambda o, r: pids.append(o._worker.pid) if o._worker is not None else None,
    )  # fmt: skip
    assert len(serial) == len(parallel) > 10
    assert parallel == serial  # every number, every flag, every window
    assert health == {"state": "on", "windows": len(parallel), "failures": 0}
    assert len(set(pids)) == 1 and not _alive(pids[0])  # closed with the observer


@pytest.mark.slow
@pytest.mark.slow
def test_a_worker_that_dies_leaves_this_process_to_estimate_without_a_changed_number(
    converter_recording, caplog
):
    serial, _, _ = _estimates(converter_recording, parallel=False)

    def kill_after_window_5(obs, result):
        if result.index == 5 and obs._worker is not None:
            os.kill(obs._worker.pid, signal.SIGKILL)

    with caplog.at_level(logging.WARNING, logger="observer.service.circuit_worker"):
        parallel, obs, health = _estimates(
            converter_recording, parallel=True, on_window=kill_after_window_5
        )
    assert parallel == serial
    assert health["state"] == "failed" and health["failures"] == 1
    assert 0 < health["windows"] < len(parallel)
    assert any("both circuits are estimated in this process" in m for m in caplog.messages)


def test_parallel_circuits_auto_follows_the_cpus_unless_the_environment_says_off(monkeypatch):
    monkeypatch.delenv("DCOBSERVER_PARALLEL_CIRCUITS", raising=False)
    assert parallel_wanted("on") and not parallel_wanted("off")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert parallel_wanted("auto")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert not parallel_wanted("auto")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    monkeypatch.setenv("DCOBSERVER_PARALLEL_CIRCUITS", "off")
    assert not parallel_wanted("auto") and parallel_wanted("on")


def test_the_daemon_starts_its_worker_with_itself_and_stops_it_with_itself(
    converter_recording, tmp_path
):
    """parallel_circuits = "on": the worker starts with the daemon (windows before it is
    ready estimate both circuits here) and is gone once the daemon stops."""
    from bench.tracker_bench import RecordingSource

    config = Config(
        observer=dataclasses.replace(CONFIG, parallel_circuits="on"),
        zenoh=ZenohConfig(listen=[f"tcp/127.0.0.1:{free_port()}"]),
        log=LogConfig(dir=str(tmp_path / "log")),
    )
    daemon = Daemon(config, RecordingSource(converter_recording), sample_rate_hint_hz=2000.0)
    daemon.start()
    try:
        worker = daemon.observer._worker
        assert worker is not None and worker.wait_ready(READY_S)
        pid = worker.pid
        assert daemon.finished.wait(120)
        parallel = daemon.health()["observer"]["parallel"]
    finally:
        assert daemon.stop() == []
    assert parallel["state"] == "on" and parallel["failures"] == 0
    assert pid is not None and not _alive(pid)


def test_a_window_ended_by_an_unexpected_error_does_not_leave_a_busy_worker_behind(
    converter_recording, monkeypatch
):
    """The field's estimate fails with an error no window expects while the armature's is in
    the worker: the next window finds the worker busy, stops it, and estimates here."""
    from observer.service import window_observer

    ring = RingBuffer(20_000)
    obs = SlidingWindowObserver(ring, CONFIG, parallel=True)
    assert obs.start_worker(wait_s=READY_S)
    pid = obs._worker.pid
    original = window_observer.run_estimator
    calls = []

    def field_breaks_once(prep):
        calls.append(prep.circuit)
        if prep.circuit == "field" and calls.count("field") == 3:
            raise RuntimeError("a bug")
        return original(prep)

    monkeypatch.setattr(window_observer, "run_estimator", field_breaks_once)
    raised, estimated = 0, 0
    try:
        for block in _blocks(converter_recording):
            ring.write(block)
            try:
                estimated += sum(r.estimate is not None for r in obs.process_ready())
            except RuntimeError:
                raised += 1
    finally:
        obs.close()
    assert raised == 1 and estimated > 10
    assert obs.worker_failures == 1 and obs.parallel_state == "failed"
    assert "armature" in calls  # the windows after it estimated the armature here
    assert not _alive(pid)
