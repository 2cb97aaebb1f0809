"""What the adapters share: backoff, the device clock, the pump thread and its bounded buffer."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.pump import Backoff, DeviceClock, PumpedSource
from tests.drivers.peers import wait_for


def test_backoff_grows_to_its_maximum_and_resets():
    b = Backoff(0.1, 0.5, 2.0)
    assert [b.next_delay() for _ in range(5)] == pytest.approx([0.1, 0.2, 0.4, 0.5, 0.5])
    b.reset()
    assert b.next_delay() == pytest.approx(0.1)
    with pytest.raises(ValueError, match="backoff"):
        Backoff(1.0, 0.5)


def test_device_clock_unwraps_and_stays_on_the_device_time_base():
    clock = DeviceClock(wrap=2**16, tick_ns=1000, max_step_ns=10**9)
    raw = (np.arange(10) * 20_000 + 60_000) % 2**16  # wraps after the first sample
    t = clock.convert(raw, host_ns=5_000_000_000)
    np.testing.assert_array_equal(np.diff(t), np.full(9, 20_000_000))
    assert t[-1] == 5_000_000_000  # anchored: the last sample arrived at host_ns
    more = clock.convert(np.array([(raw[-1] + 500) % 2**16]), host_ns=9_999_999_999)
    assert more[0] == t[-1] + 500_000  # follows the device, not the host
    assert clock.reanchors == 1


def test_device_clock_reanchors_on_a_device_restart_and_never_goes_back():
    clock = DeviceClock(wrap=2**32, tick_ns=1000, max_step_ns=10**9)
    t1 = clock.convert(np.array([1_000_000, 1_000_500]), host_ns=10_000_000)
    t2 = clock.convert(np.array([0, 500]), host_ns=10_100_000)  # restarted: counter went back
    assert clock.reanchors == 2
    assert t2[0] > t1[-1] and t2[1] - t2[0] == 500_000


class ScriptedDevice(PumpedSource):
    """A device driven by the test: each _receive takes the next scripted step."""

    name = "scripted"

    def __init__(self, script, **kw):
        super().__init__(**kw)
        self.script = list(script)
        self.connects = 0
        self.idle = threading.Event()

    def _connect(self):
        self.connects += 1

    def _disconnect(self):
        pass

    def _receive(self, timeout):
        if not self.script:
            self.idle.set()
            self._stop.wait(timeout)
            return None
        step = self.script.pop(0)
        if isinstance(step, Exception):
            raise step
        t = np.arange(step[0], step[1], dtype=np.int64)
        return t, {"va": t.astype(float)}


def test_pump_survives_any_exception_counts_it_and_reconnects():
    src = ScriptedDevice(
        [(0, 10), KeyError("a bug in a decoder"), (10, 20), OSError("port gone"), (20, 30)],
        backoff=Backoff(0.001, 0.01),
    )
    with src:
        src.read(timeout=1)
        wait_for(src.idle.is_set, 5, "the script to run")
        blocks = []
        while (b := src.read(timeout=0.1)) is not None:
            blocks.append(b)
        health = src.health()
    assert health["errors"] == 2 and health["reconnects"] == 2 and src.connects == 3
    assert "port gone" in health["last_error"]
    assert health["received_samples"] == 30


def test_overrun_drops_the_oldest_samples_and_counts_them():
    src = ScriptedDevice([(0, 40), (40, 80), (80, 100)], buffer_samples=50)
    with src:
        first = src.read(timeout=1)  # starts the pump; the first step may be read at once
        wait_for(src.idle.is_set, 5, "the script to run")
        rest = src.read(timeout=1)
        health = src.health()
    got = np.concatenate([b.t_ns for b in (first, rest) if b is not None])
    assert got[-1] == 99 and np.all(np.diff(got) > 0)
    assert health["overrun_samples"] == 100 - got.size == health["dropped"]
    assert health["samples"] + health["overrun_samples"] == health["received_samples"] == 100
