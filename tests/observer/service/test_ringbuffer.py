"""Ring buffer: wrap-around, windows, and a real producer thread against a real consumer."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from drivers.base import SampleBlock
from observer.service.ringbuffer import RingBuffer

CH = ("va", "ia")


def _block(start, n, period_ns=1000):
    k = np.arange(start, start + n)
    return SampleBlock(k * period_ns, {"va": k.astype(float), "ia": -k.astype(float)})


def test_write_and_read_back_across_the_wrap():
    ring = RingBuffer(10, CH)
    ring.write(_block(0, 7))
    first = ring.read_new()
    assert first is not None and first.start == 0 and list(first.signals["va"]) == list(range(7))
    ring.write(_block(7, 6))  # wraps
    second = ring.read_new()
    assert second is not None and list(second.t_ns) == [k * 1000 for k in range(7, 13)]
    assert list(second.signals["ia"]) == [-k for k in range(7, 13)]
    assert ring.read_new() is None
    last = ring.latest(4)
    assert last is not None and list(last.signals["va"]) == [9, 10, 11, 12]
    assert ring.overruns == 0


def test_window_between_times():
    ring = RingBuffer(100, CH)
    ring.write(_block(0, 50))
    w = ring.between(10_000, 20_000)  # (10 us, 20 us]
    assert w is not None and list(w.signals["va"]) == list(range(11, 21))
    assert ring.between(60_000, 70_000) is None


def test_missing_channel_is_nan():
    ring = RingBuffer(8, ("va", "vf"))
    ring.write(SampleBlock(np.arange(3), {"va": np.ones(3)}))
    w = ring.latest(3)
    assert w is not None and np.all(np.isnan(w.signals["vf"])) and np.all(w.signals["va"] == 1)


def test_overrun_is_counted_never_silent():
    ring = RingBuffer(10, CH)
    ring.write(_block(0, 8))
    ring.write(_block(8, 8))  # the consumer read nothing: 6 samples are gone
    w = ring.read_new()
    assert ring.overruns == 1 and ring.overrun_samples == 6
    assert w is not None and list(w.signals["va"]) == list(range(6, 16))
    ring.write(_block(16, 25))  # a block longer than the ring keeps its tail
    assert ring.overrun_samples == 6 + 15
    w = ring.read_new()
    assert w is not None and list(w.signals["va"]) == list(range(31, 41))


def test_write_does_not_allocate_storage():
    ring = RingBuffer(64, CH)
    ids = (id(ring._t), id(ring._data), ring._data.ctypes.data)
    for i in range(20):
        ring.write(_block(i * 7, 7))
    assert (id(ring._t), id(ring._data), ring._data.ctypes.data) == ids


@pytest.mark.parametrize("capacity,consumer_delay", [(8192, False), (64, True)])
def test_threads_every_sample_seen_once_or_counted(capacity, consumer_delay):
    """A producer thread writes 200 blocks; the consumer sees each sample once, in order,
    or counts it as overrun: seen + lost == written, and every copy is internally consistent."""
    ring = RingBuffer(capacity, CH)
    done = threading.Event()
    go = threading.Event()
    lapped = threading.Event()
    n_blocks, n = 200, 37

    def produce():
        go.wait()
        for b in range(n_blocks):
            ring.write(_block(b * n, n))
            if b == 2:
                lapped.set()  # 111 samples written: a 64-sample ring has lapped
        done.set()

    seen = []
    thread = threading.Thread(target=produce)
    thread.start()
    go.set()
    if consumer_delay:
        lapped.wait(10)  # the consumer starts late: an overrun is certain
    slow = threading.Event()
    while True:
        finished = done.is_set()
        w = ring.read_new()
        if w is not None:
            # Consistency: t, va and ia of each sample belong together.
            assert np.array_equal(w.t_ns, (w.signals["va"] * 1000).astype(np.int64))
            assert np.array_equal(w.signals["ia"], -w.signals["va"])
            seen.append(w.signals["va"].astype(np.int64))
        if consumer_delay:
            slow.wait(0.0005)  # a consumer slower than the producer
        if finished and w is None:
            break
        if w is None:
            ring.wait_for(ring.written + 1, timeout=0.01)
    thread.join()
    seen_all = np.concatenate(seen)
    assert np.all(np.diff(seen_all) > 0)
    assert seen_all.size + ring.overrun_samples == n_blocks * n
    if consumer_delay:
        assert ring.overrun_samples > 0 and ring.overruns > 0
    else:
        assert ring.overrun_samples == 0


def test_wait_for_time_wakes_on_write():
    ring = RingBuffer(100, CH)
    woke = threading.Event()

    def consumer():
        if ring.wait_for_time(30_000, timeout=10):
            woke.set()

    t = threading.Thread(target=consumer)
    t.start()
    ring.write(_block(0, 10))
    assert not woke.wait(0.05)
    ring.write(_block(10, 30))
    assert woke.wait(5)
    t.join()
