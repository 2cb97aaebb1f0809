"""Seconds of log lost when the daemon is killed with SIGKILL, and its automatic recovery.

Runs ``dcobserver run`` as a real process on a replay of a simulated 12-bit P-12 recording
(2 kHz, looping at ``--speed`` x real time, the log's default ``flush_s``), kills it with
SIGKILL at a random moment (after a random number of the log file's growths, then a random
fraction of a flush interval), starts it again, and so on ``--kills`` times; a last start
recovers the last cut file and is stopped with SIGTERM. Then, for every kill:

* the cut file was recovered automatically at the next start: a valid file under its final
  name (mcap's indexed reader reads every message back), the cut original gone;
* **seconds lost** = the kill's wall-clock time - the ``log_time`` of the last ``/samples``
  message recovered (the wall-clock time its first sample reached the daemon). At the replay's
  ``--speed`` that is ``speed`` x as many seconds of data; at a drive's real time, the same.

Usage::

    python -m bench.crash_loss [--kills N] [--speed X] [--seed S]
"""

from __future__ import annotations

import argparse
import os
import queue
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.common import adc_full_scale, machine_description  # noqa: E402
from observer.estimation.motor import P12  # noqa: E402
from observer.recording import final_path, quantise, write_recording  # noqa: E402
from observer.simulation.simulate import simulate  # noqa: E402


@dataclass(frozen=True)
class Kill:
    """One SIGKILL and what the next start made of the file it cut."""

    cut: Path  # the file being written when the daemon was killed (temporary name)
    killed_ns: int  # wall clock, just before SIGKILL
    recovered: Path  # its final name, written by the next start
    last_samples_ns: int  # log_time of the last /samples message recovered
    messages: int

    @property
    def lost_s(self) -> float:
        return (self.killed_ns - self.last_samples_ns) / 1e9


class Daemon:
    """``dcobserver run`` in a process, its stderr lines collected by a thread."""

    def __init__(self, config: Path) -> None:
        env = {**os.environ, "PYTHONPATH": str(REPO)}
        env.pop("NOTIFY_SOCKET", None)
        env.pop("WATCHDOG_USEC", None)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "observer.cli", "run", "--config", str(config),
             "--quiet-estimates"],
            cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        self.lines: queue.Queue[str] = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append(line)
            self.lines.put(line)

    def wait_line(self, pattern: str, timeout: float = 60.0) -> re.Match[str]:
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            match = regex.search(line)
            if match:
                return match
        tail = "".join(self.stderr[-15:])
        raise RuntimeError(f"no line matching {pattern!r} within {timeout} s:\n{tail}")

    def kill(self, sig: int = signal.SIGKILL) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.proc.wait(30)


def write_config(folder: Path, recording: Path, speed: float) -> Path:
    """A daemon config: the replay looping at ``speed``, the log in ``folder/logs``."""
    config = folder / "crash.toml"
    config.write_text(f"""
[source]
kind = "replay"
[source.options]
path = "{recording}"
speed = {speed}
block_s = 0.05
loop = true
[observer]
drive_id = "crash"
hop_s = 0.25
cold_particles = 20
cold_iterations = 10
warm_particles = 10
warm_iterations = 8
[zenoh]
enabled = false
[log]
dir = "logs"
""")
    return config


def make_recording(folder: Path) -> Path:
    """20 s of a simulated P-12 at 2 kHz as its 12-bit drive ADC measures it."""
    rec = simulate(P12, duration_s=20.0, sample_rate_hz=2000.0, noise=0.002, seed=11)
    path = folder / "p12-adc.mcap"
    write_recording(quantise(rec, adc_full_scale(P12), bits=12), path)
    return path


_WRITING = r"MCAP log: writing \S+ \(as (\S+) until it is complete\)"


def _wait_growths(path: Path, growths: int, timeout: float = 30.0) -> None:
    """Until ``path`` has grown ``growths`` times (each growth: a flushed chunk)."""
    size = path.stat().st_size
    deadline = time.monotonic() + timeout
    seen = 0
    while seen < growths:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{path} did not grow {growths} times within {timeout} s")
        time.sleep(0.01)  # polling the file: the event waited for is its growth
        now = path.stat().st_size
        if now > size:
            seen, size = seen + 1, now


def kill_and_restart(
    folder: Path, recording: Path, *, kills: int, speed: float, seed: int
) -> list[Kill]:
    """``kills`` SIGKILLs at random moments, each followed by a restart that recovers the cut."""
    from mcap.reader import make_reader

    rng = np.random.default_rng(seed)
    config = write_config(folder, recording, speed)
    logs = folder / "logs"
    cuts: list[tuple[Path, int]] = []
    for k in range(kills + 1):
        daemon = Daemon(config)
        try:
            # The log thread recovers the previous cut before it opens the new file.
            temp = logs / daemon.wait_line(_WRITING).group(1)
            if k == kills:
                break
            _wait_growths(temp, int(rng.integers(1, 6)))
            threading.Event().wait(float(rng.uniform(0.0, 0.5)))  # anywhere in a flush interval
            killed_ns = time.time_ns()
            daemon.kill(signal.SIGKILL)
            cuts.append((temp, killed_ns))
        finally:
            code = daemon.kill(signal.SIGTERM)
        if k == kills and code != 0:
            raise RuntimeError(f"the last daemon exited with {code}")
    results = []
    for temp, killed_ns in cuts:
        final = final_path(temp)
        if temp.exists() or not final.exists():
            raise RuntimeError(f"{temp} was not recovered to {final}")
        with final.open("rb") as stream:
            reader = make_reader(stream)
            times = [m.log_time for _s, _c, m in reader.iter_messages(topics=["/samples"])]
            count = reader.get_summary().statistics.message_count  # type: ignore[union-attr]
        results.append(Kill(temp, killed_ns, final, max(times), count))
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=20)
    parser.add_argument("--speed", type=float, default=4.0, help="replay speed (x real time)")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="dcobserver-crash-") as tmp:
        folder = Path(tmp)
        kills = kill_and_restart(
            folder, make_recording(folder), kills=args.kills, speed=args.speed, seed=args.seed
        )
    lost = [k.lost_s for k in kills]
    print(f"# SIGKILL x {len(kills)}, replay at {args.speed:g}x real time, [log] flush_s = 0.5")
    print(f"# {machine_description()}")
    print("| kills | recovered automatically | seconds lost: median | max |")
    print("|---|---|---|---|")
    print(f"| {len(kills)} | {len(kills)} | {statistics.median(lost):.2f} | {max(lost):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
