"""The daemon's MCAP log read by mcap's own reader: one wall clock, metadata, counts, retention."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.decoder import DecoderFactory as McapDecoderFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from observer import __version__
from observer.config import Config, LogConfig, ObserverConfig, ZenohConfig
from observer.recording import adc_scales, read_mcap, write_recording
from observer.service.daemon import Daemon
from observer.service.logfiles import Retention
from observer.service.mcaplog import McapLog
from replay.source import ReplaySource, iter_mcap_blocks

JS = Path(__file__).resolve().parents[2] / "js"
OBS = ObserverConfig(
    drive_id="shovel1", motor_id="hoist", window_s=1.0, hop_s=0.25, cold_particles=20,
    cold_iterations=10, warm_particles=10, warm_iterations=8, health_s=0.2, buffer_s=16.0,
    max_lag_windows=1000,
)  # fmt: skip
# The replay runs as fast as it can: a buffer of the whole recording and no skipping of late
# windows make the daemon estimate every window, so the log's last estimate is a tracked value
# and not whatever the recording's last window alone says (its end is not informative).


class JsonDecoderFactory(McapDecoderFactory):
    """mcap's reader decodes protobuf with mcap-protobuf-support; JSON with this."""

    def decoder_for(self, message_encoding, schema):
        return json.loads if message_encoding == "json" else None


def _wait(predicate, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture(scope="module")
def adc_daemon_log(tmp_path_factory, p12_adc_recording):
    """A daemon's log of the 12-bit P-12 recording: (file, config file, wall ns before, after)."""
    tmp_path = tmp_path_factory.mktemp("adc-log")
    recording = tmp_path / "adc.mcap"
    write_recording(p12_adc_recording, recording)
    config_file = tmp_path / "hoist.toml"
    config_file.write_text("# the configuration text travels with every log file\n")
    log_dir = tmp_path / "logs"
    config = Config(observer=OBS, zenoh=ZenohConfig(enabled=False), log=LogConfig(dir=str(log_dir)))
    source = ReplaySource.of(recording, speed=0.0, block_s=0.05)
    before_ns = time.time_ns()
    daemon = Daemon(config, source, config_path=str(config_file))
    daemon.start()
    try:
        assert daemon.finished.wait(60), "the replay did not end"
    finally:
        daemon.stop()
    after_ns = time.time_ns()
    assert daemon.health()["log"]["retention"]["deleted_files"] == 0
    (path,) = log_dir.glob("*.mcap")
    return path, config_file, before_ns, after_ns


def test_daemon_log_has_one_wall_clock_counts_and_describes_itself(
    adc_daemon_log, p12_adc_recording
):
    path, config_file, before_ns, after_ns = adc_daemon_log
    with path.open("rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory(), JsonDecoderFactory()])
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        topics: dict[str, list] = {}
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            topics.setdefault(channel.topic, []).append((message, decoded))
    # One time base: every log_time is wall clock, within the run.
    for topic, messages in topics.items():
        times = [m.log_time for m, _ in messages]
        assert before_ns <= min(times) and max(times) <= after_ns, topic
    # The data's own clock is in the payload: the recording's times, exactly.
    blocks = [decoded for _, decoded in topics["/samples"]]
    t0 = [b.t0_ns for b in blocks]
    expected = np.rint(p12_adc_recording.t * 1e9).astype(np.int64)
    assert t0[0] == expected[0] and sum(b.n_samples for b in blocks) == expected.size
    assert all(len(b.ia.counts) == b.n_samples and not len(b.ia.values) for b in blocks)
    estimates = [decoded for _, decoded in topics["/estimate"]]
    assert estimates and all(e["t_ns"] <= expected[-1] for e in estimates)  # data time

    # Self-describing: software, ids, configuration, channel units and scales.
    info = metadata["dcobserver.log"]
    assert (info["software"], info["version"]) == ("dcobserver", __version__)
    assert (info["drive_id"], info["motor_id"], info["source"]) == ("shovel1", "hoist", "replay")
    assert "wall-clock" in info["time_base"]
    assert metadata["dcobserver.config"]["toml"] == config_file.read_text()
    assert json.loads(metadata["dcobserver.config"]["settings_json"])["observer"]["hop_s"] == 0.25
    ia = json.loads(metadata["dcobserver.channels"]["ia"])
    assert ia["unit"] == "A" and ia["adc"] == adc_scales(p12_adc_recording.metadata)["ia"]._asdict()

    # The recording reader gets the samples back exactly, with their ADC scales.
    back = read_mcap(path)
    assert all(np.array_equal(back[c], p12_adc_recording[c]) for c in back.channels)
    assert back.metadata["adc"] == p12_adc_recording.metadata["adc"]
    assert back.metadata["motor_id"] == "hoist"


@pytest.fixture(scope="module")
def node_modules():
    """tests/js installed (``npm ci``, as .ci/run does) where node exists; else skip."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        pytest.skip("node/npm not installed: cannot run the TypeScript MCAP reader Foxglove uses")
    # The entry point itself, not just the package folder: a half-installed tree
    # (e.g. node_modules copied without its dist/ folders) needs a fresh npm ci.
    if not (JS / "node_modules" / "@mcap" / "core" / "dist" / "esm" / "index.js").is_file():
        done = subprocess.run(
            [npm, "ci", "--no-audit", "--no-fund"], cwd=JS, capture_output=True, text=True,
            timeout=300,
        )  # fmt: skip
        assert done.returncode == 0, f"npm ci in {JS} failed:\n{done.stderr[-2000:]}"
    return node


def test_foxglove_typescript_reader_sees_one_clock_and_the_metadata(
    adc_daemon_log, node_modules, p12_adc_recording
):
    path, config_file, before_ns, after_ns = adc_daemon_log
    done = subprocess.run(
        [node_modules, str(JS / "check_log.mjs"), str(path)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout)
    topics = seen["topics"]
    assert set(topics) == {"/samples", "/estimate", "/health"}
    # One timeline: every topic's log times lie within the run's wall-clock seconds.
    for topic, entry in topics.items():
        assert before_ns <= int(entry["minLogTime"]) <= int(entry["maxLogTime"]) <= after_ns, topic
    assert before_ns <= int(seen["messageStartTime"]) <= int(seen["messageEndTime"]) <= after_ns
    # Samples decoded from the protobuf schema in the file, as Foxglove decodes them.
    samples = topics["/samples"]
    assert (samples["schema"], samples["encoding"]) == ("dcobserver.SampleBlock", "protobuf")
    last = samples["last"]
    scale = p12_adc_recording.metadata["adc"]["ia"]
    assert len(last["ia"]["counts"]) == last["n_samples"] and last["ia"]["lsb"] == scale["lsb"]
    t_last = int(last["t0_ns"]) + (last["n_samples"] - 1) * int(last["period_ns"])
    assert t_last == round(p12_adc_recording.t[-1] * 1e9)  # the data's own clock, in the payload
    assert last["ia"]["min"] <= last["ia"]["mean"] <= last["ia"]["max"]
    estimate = topics["/estimate"]["last"]
    assert estimate["motor_id"] == "hoist" and estimate["armature"]["R"] == pytest.approx(3.5, 0.05)
    # The metadata records say what made the file.
    meta = seen["metadata"]
    assert {
        "dcobserver.log",
        "dcobserver.config",
        "dcobserver.channels",
        "dcobserver.recording",
    } <= set(meta)
    assert meta["dcobserver.log"]["version"] == __version__
    assert meta["dcobserver.log"]["motor_id"] == "hoist"
    assert meta["dcobserver.config"]["toml"] == config_file.read_text()
    assert json.loads(meta["dcobserver.channels"]["omega"])["unit"] == "rad/s"


def test_retention_keeps_the_newest_data_within_a_small_budget(tmp_path, p12_recording, caplog):
    budget = 100_000
    cfg = LogConfig(
        dir=str(tmp_path), rotate_mb=0.03, flush_s=0.02, block_s=0.1, max_total_gb=budget / 1e9
    )
    log = McapLog(cfg, "fill")
    log.start()
    t_ns = np.rint(p12_recording.t * 1e9).astype(np.int64)
    step = 400
    with caplog.at_level(logging.INFO, logger="observer.service"):
        for i in range(0, t_ns.size, step):
            sl = slice(i, i + step)
            written = log.health()["bytes"]
            log.submit_samples(t_ns[sl], {c: p12_recording[c][sl] for c in p12_recording.channels})
            # Each block reaches the disk before the next: rotation sees the file's real size.
            assert _wait(lambda w=written: log.health()["bytes"] != w, 10)
        log.close()
    files = sorted(tmp_path.glob("*.mcap"))
    health = log.health()["retention"]
    assert health["deleted_files"] >= 3 and "deleted" in caplog.text
    assert sum(f.stat().st_size for f in files) <= budget
    # What is left is the newest data, up to the very last sample, without a hole.
    kept = [b for f in files for b in iter_mcap_blocks(f)]
    kept_t = np.concatenate([b.t_ns for b in kept])
    assert kept_t[-1] == t_ns[-1]
    assert np.array_equal(kept_t, t_ns[t_ns.size - kept_t.size :])


def test_retention_deletes_oldest_first_only_this_drives_files_never_the_open_one(tmp_path):
    now = time.time()
    names = [f"dcobserver-d1-2026010{k}T000000-1-0001.mcap" for k in range(1, 6)]
    motor = tmp_path / "dcobserver-d1-crowd-20260101T000000-1-0001.mcap"  # another motor's
    motor.write_bytes(b"x" * 5000)
    for k, name in enumerate(names):
        (tmp_path / name).write_bytes(b"x" * 1000)
        os.utime(tmp_path / name, (now - (10 - k) * 86400, now - (10 - k) * 86400))
    other = tmp_path / "dcobserver-d2-20260101T000000-1-0001.mcap"
    other.write_bytes(b"x" * 5000)
    retention = Retention(tmp_path, "dcobserver-d1", max_total_bytes=1500, max_age_s=0)
    deleted = retention.enforce(keep=tmp_path / names[0], now=now)  # the open one: never
    assert [p.name for p in deleted] == names[1:4]  # nor the newest, though over the budget
    assert other.exists() and motor.exists()
    assert (tmp_path / names[0]).exists() and (tmp_path / names[4]).exists()
    by_age = Retention(tmp_path, "dcobserver-d1", max_total_bytes=0, max_age_s=5.5 * 86400)
    assert [p.name for p in by_age.enforce(now=now)] == [names[0]]  # 10 days old
    assert by_age.health()["deleted_files"] == 1 and by_age.health()["files"] == 1
