"""CAN adapter: DBC decoding, pairing, faults, reconnect and overruns on python-can buses."""

from __future__ import annotations

import itertools
import json
import os
import shutil
import subprocess
import sys
import threading
import time

import can
import numpy as np
import pytest

from drivers import source_class
from drivers.base import SourceError
from drivers.can_bus import P12_DBC, CanOptions, CanSource
from drivers.fake_drive import CanFakeDrive
from observer.estimation import estimate_recording
from observer.estimation.motor import P12
from observer.recording import read_recording
from observer.simulation.drive_stream import DriveStream
from tests.drivers.contract import SourceContract
from tests.drivers.peers import REPO, collect, concat, to_recording, wait_for

RATE = 2000.0
_channels = itertools.count()


class FakeCanPeer:
    """A CAN fake drive on its own thread and its own ``virtual`` bus."""

    def __init__(self, channel: str, *, seed: int = 0, speedup: float = 1.0, duration=None):
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.drive = CanFakeDrive(
            DriveStream(sample_rate_hz=RATE, seed=seed), self.bus, speedup=speedup
        )
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.drive.run, args=(self.stop, duration))
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10)
        self.bus.shutdown()


@pytest.fixture
def channel():
    return f"dcobserver-test-{os.getpid()}-{next(_channels)}"


@pytest.fixture
def peers():
    started: list[FakeCanPeer] = []

    def start(channel: str, **kw) -> FakeCanPeer:
        started.append(FakeCanPeer(channel, **kw))
        return started[-1]

    yield start
    for p in started:
        p.close()


def _source(channel: str, **kw) -> CanSource:
    kw.setdefault("reconnect_max_s", 0.2)
    return CanSource(CanOptions(interface="virtual", channel=channel, **kw))


class TestCanContract(SourceContract):
    min_samples = 200

    def make_source(self, request, tmp_path):
        ch = f"dcobserver-contract-{os.getpid()}-{next(_channels)}"
        peer = FakeCanPeer(ch)
        request.addfinalizer(peer.close)
        return _source(ch)


def test_registered_and_config_errors_are_clear(tmp_path):
    assert source_class("can") is CanSource
    from observer.config import ConfigError

    src = CanSource.from_config(
        {"interface": "virtual", "channel": "x", "dbc": str(P12_DBC)},
        source="c.toml", base_dir=tmp_path,
    )  # fmt: skip
    assert src.options.interface == "virtual"
    with pytest.raises(ConfigError, match="Message.Signal"):
        CanSource.from_config({"signals": {"va": "nodot"}}, source="c.toml", base_dir=tmp_path)
    with pytest.raises(SourceError, match="no signal 'Nope'"):
        CanSource(signals={"va": "DriveArmature.Nope"})
    with pytest.raises(SourceError, match="cannot load DBC"):
        CanSource(dbc=str(tmp_path / "missing.dbc"))


def test_end_to_end_estimates_within_tolerance(channel, peers):
    with _source(channel) as src:
        src.read(timeout=0.1)  # subscribe before the drive starts
        peers(channel, seed=4, speedup=3)
        blocks = collect(src, int(5.4 * RATE), timeout=20)
    health = src.health()  # after close: the pump has stopped, the counters agree
    rec = to_recording(blocks, RATE)
    assert rec.n_samples >= 5.2 * RATE and health["errors"] == 0 and health["dropped"] == 0
    assert 0 <= health["frames"] - 2 * health["received_samples"] <= 1  # one may await its pair
    est = estimate_recording(rec)
    f, a = est["field"], est["armature"]
    assert f.resistance_ohm == pytest.approx(P12.field_resistance_ohm, rel=0.01)
    assert f.inductance_h == pytest.approx(P12.field_inductance_h, rel=0.02)
    assert a.resistance_ohm == pytest.approx(P12.armature_resistance_ohm, rel=0.01)
    # La from a ~5 s window varies by +-5 % with where the window starts (the estimator's
    # sensitivity to the window's excitation, not the transport's).
    assert a.inductance_h == pytest.approx(P12.armature_inductance_h, rel=0.08)
    assert a.emf_constant_h == pytest.approx(P12.emf_constant_h, rel=0.01)


def test_unknown_ids_short_frames_and_lost_frames_are_counted_and_skipped(channel):
    """The test is the peer: it sends the drive's frames, with faults, on a virtual bus."""
    bus = can.Bus(interface="virtual", channel=channel)
    drive = CanFakeDrive(DriveStream(sample_rate_hz=RATE, seed=2), bus)
    samples = drive.stream.take(300)
    try:
        with _source(channel, stale_timeout_s=0) as src:
            src.read(timeout=0.1)
            for k in range(300):
                armature, field = drive.frames_of(k, samples[k])
                if k % 50 == 10:  # a foreign node's traffic
                    bus.send(
                        can.Message(arbitration_id=0x7FF, data=b"\x01\x02", is_extended_id=False)
                    )
                if k == 150:  # a bus error, as a controller reports it
                    bus.send(can.Message(is_error_frame=True, is_extended_id=False))
                if k != 100:  # sample 100 loses its armature frame
                    bus.send(armature)
                if k % 60 == 20:  # a short frame with a known ID instead of the real one
                    short = field.data[:3]
                    bus.send(can.Message(arbitration_id=field.arbitration_id, data=short,
                                         is_extended_id=False))  # fmt: skip
                else:
                    bus.send(field)
            wait_for(lambda: src.health()["received_samples"] >= 300 - 6, 10, "the frames")
            blocks = collect(src, 300 - 6, timeout=5)
            health = src.health()
    finally:
        bus.shutdown()
    assert health["unknown_ids"] == 6 and health["error_frames"] == 1
    assert health["short_frames"] == 5
    assert health["errors"] == 5  # short frames are bad frames; foreign IDs are not
    assert health["dropped"] == 6 and health["incomplete_samples"] == 6
    t, sig = concat(blocks)
    lost = {k for k in range(300) if k % 60 == 20} | {100}
    kept = np.array([k for k in range(300) if k not in lost])
    np.testing.assert_array_equal(np.rint((t - t[0]) * RATE / 1e9).astype(int), kept - kept[0])
    # Decoded values equal the simulated ones to the DBC's resolution.
    np.testing.assert_allclose(sig["va"], samples[kept, 0], atol=0.005 + 1e-9)
    np.testing.assert_allclose(sig["if"], samples[kept, 3], atol=0.00005 + 1e-9)
    np.testing.assert_allclose(sig["omega"], samples[kept, 4], atol=0.005 + 1e-9)


def test_peer_disappears_and_comes_back(channel, peers):
    with _source(channel, stale_timeout_s=0.3) as src:
        src.read(timeout=0.1)
        first = peers(channel, seed=1, speedup=2)
        collect(src, 200, timeout=20)
        first.close()  # the drive goes silent
        wait_for(lambda: not src.health()["connected"], 10, "the source to see the silence")
        assert src.health()["errors"] >= 1
        peers(channel, seed=3, speedup=2)  # the drive restarts: its clock and counter restart
        wait_for(
            lambda: src.health()["connected"] and src.health()["reconnects"] >= 1, 10, "reconnect"
        )
        blocks = collect(src, 1000, timeout=20)
    t, _ = concat(blocks)
    assert np.all(np.diff(t) > 0)


def test_consumer_slower_than_bus_overruns_are_counted(channel, peers):
    with _source(channel, buffer_samples=200, stale_timeout_s=0) as src:
        src.read(timeout=0.1)
        peers(channel, seed=6, speedup=4, duration=1.0)
        wait_for(lambda: src.health()["received_samples"] >= 1000, 20, "1000 samples on the bus")
        got = 0
        while (b := src.read(timeout=0.3)) is not None:
            got += len(b)
        health = src.health()
    assert health["overrun_samples"] >= 1000 - 200
    assert health["dropped"] == health["overrun_samples"]
    assert health["samples"] + health["overrun_samples"] == health["received_samples"]
    assert got == health["samples"]


def _netns_available() -> bool:
    if not shutil.which("unshare") or not shutil.which("ip"):
        return False
    probe = subprocess.run(
        ["unshare", "-rn", "sh", "-c", "ip link set lo up"], capture_output=True, timeout=10
    )
    return probe.returncode == 0


@pytest.mark.skipif(not _netns_available(), reason="cannot create a network namespace here")
@pytest.mark.slow
@pytest.mark.slow
def test_cross_process_udp_multicast_inside_a_private_network_namespace(tmp_path):
    """Fake drive and reader in two processes, in a namespace whose only interface is lo."""
    out = tmp_path / "can.csv"
    group = "239.74.163.2"
    py = sys.executable
    script = (
        "set -e; ip link set lo up; ip link set lo multicast on; "
        "ip route add 224.0.0.0/4 dev lo; "
        f"{py} tests/drivers/can_netns_reader.py {group} 3000 {out} -- "
        f"--channel {group} --speedup 3 --seed 8 --duration 30"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.run(
        ["unshare", "-rn", "sh", "-c", script],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    health = json.loads(proc.stdout.strip().splitlines()[-1])
    assert health["errors"] == 0 and health["received_samples"] >= 3000
    rec = read_recording(out)
    assert rec.n_samples >= 2900
    est = estimate_recording(rec, ("field",))
    assert est["field"].resistance_ohm == pytest.approx(P12.field_resistance_ohm, rel=0.01)
    assert est["field"].inductance_h == pytest.approx(P12.field_inductance_h, rel=0.03)


def test_without_a_device_clock_samples_carry_host_monotonic_time(channel, peers):
    before = time.monotonic_ns()
    with _source(channel, time="") as src:
        src.read(timeout=0.1)
        peers(channel, seed=1)
        blocks = collect(src, 200, timeout=20)
    after = time.monotonic_ns()
    t, _ = concat(blocks)
    assert before < t[0] and t[-1] < after and np.all(np.diff(t) > 0)
