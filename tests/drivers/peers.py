"""Helpers of the adapter tests: fake drives in subprocesses, collecting and checking samples."""

from __future__ import annotations

import os
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from drivers.base import CHANNELS, SampleBlock, Source
from observer.recording import Recording
from observer.simulation.converter import DEFAULT_PRESET, PRESETS
from observer.simulation.drive_stream import DriveStream

REPO = Path(__file__).resolve().parents[2]


class FakeDrive:
    """``dcobserver fake-drive ...`` in a subprocess; ``line`` is its first stdout line."""

    def __init__(self, *args: str, timeout: float = 30.0) -> None:
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "observer.cli", "fake-drive", *args],
            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        )  # fmt: skip
        self.line = self._first_line(timeout)

    def _first_line(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        buf = b""
        while b"\n" not in buf:
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None and not sel.select(0):
                err = self.proc.stderr.read().decode() if self.proc.poll() is not None else ""
                self.kill()
                raise RuntimeError(f"fake drive did not announce itself: {err}")
            if sel.select(left):
                chunk = os.read(self.proc.stdout.fileno(), 4096)
                if not chunk:
                    continue
                buf += chunk
        sel.close()
        return buf.split(b"\n", 1)[0].decode()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=10)
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()

    def terminate(self) -> int:
        """SIGTERM and wait; the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=10)


def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    """Poll ``predicate`` until true; fail with ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def collect(source: Source, n_samples: int, timeout: float) -> list[SampleBlock]:
    """Read blocks until ``n_samples`` samples arrived (fails after ``timeout`` s)."""
    blocks: list[SampleBlock] = []
    total = 0
    deadline = time.monotonic() + timeout
    while total < n_samples:
        if time.monotonic() > deadline:
            raise AssertionError(f"only {total} of {n_samples} samples in {timeout} s")
        block = source.read(timeout=0.2)
        if block is not None:
            blocks.append(block)
            total += len(block)
    return blocks


def concat(blocks: list[SampleBlock]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    t = np.concatenate([b.t_ns for b in blocks])
    names = [c for c in CHANNELS if c in blocks[0].signals]
    return t, {c: np.concatenate([b.signals[c] for b in blocks]) for c in names}


def sample_indices(t_ns: np.ndarray, rate_hz: float) -> np.ndarray:
    """Sample numbers relative to the first, from device-clock times (exact multiples of dt)."""
    steps = (t_ns - t_ns[0]) * rate_hz / 1e9
    k = np.rint(steps).astype(np.int64)
    assert np.max(np.abs(steps - k)) < 0.01, "device times are not on the sample grid"
    return k


def longest_run(t_ns: np.ndarray, rate_hz: float) -> slice:
    """The longest run of consecutive sample numbers (no gap)."""
    k = sample_indices(t_ns, rate_hz)
    breaks = np.flatnonzero(np.diff(k) != 1) + 1
    edges = np.concatenate([[0], breaks, [k.size]])
    i = int(np.argmax(np.diff(edges)))
    return slice(int(edges[i]), int(edges[i + 1]))


def to_recording(blocks: list[SampleBlock], rate_hz: float) -> Recording:
    """The longest gap-free run of the blocks as a recording on the device time base."""
    t, sig = concat(blocks)
    run = longest_run(t, rate_hz)
    n = run.stop - run.start
    return Recording(t=np.arange(n) / rate_hz, signals={c: v[run] for c, v in sig.items()})


def bridged_recording(blocks: list[SampleBlock], rate_hz: float) -> tuple[Recording, int]:
    """All the blocks as a recording, missing samples linearly interpolated; and how many."""
    t, sig = concat(blocks)
    k = sample_indices(t, rate_hz)
    full = np.arange(k[-1] + 1)
    rec = Recording(t=full / rate_hz, signals={c: np.interp(full, k, v) for c, v in sig.items()})
    return rec, int(full.size - k.size)


def expected_stream(rate_hz: float, n: int, seed: int) -> np.ndarray:
    """The first ``n`` samples the fake drive with this rate and seed serves (SI, unquantised):
    its default drive, the :data:`~observer.simulation.converter.DEFAULT_PRESET`."""
    drive = PRESETS[DEFAULT_PRESET]
    return DriveStream(sample_rate_hz=rate_hz, seed=seed, drive=drive).take(n)


def locate(first: np.ndarray, expected: np.ndarray, tol: np.ndarray) -> int:
    """Index of the row of ``expected`` that equals ``first`` within ``tol`` per channel."""
    hits = np.flatnonzero(np.all(np.abs(expected - first) <= tol, axis=1))
    assert hits.size >= 1, "received sample not found in the simulated stream"
    return int(hits[0])
