"""Sustained throughput of the hardware adapters on this machine, and their CPU cost.

    python bench/adapters_throughput.py [--seconds 3]

serial   fake drive (subprocess) -> pty -> SerialAdcSource, at increasing frame rates;
         a rate is sustained when no sample is lost (dropped == 0, nothing unsent).
can      CanFakeDrive on a thread -> python-can ``virtual`` bus -> CanSource (one process;
         the sender's own CPU, measured with thread_time, is subtracted).
modbus   fake drive (subprocess, pymodbus server) <- ModbusSource polling as fast as it can.

CPU per 1000 samples is the consumer process's ``time.process_time`` (all its threads:
the adapter's pump and the reading loop) divided by the samples delivered.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from drivers.can_bus import CanSource  # noqa: E402
from drivers.fake_drive import CanFakeDrive  # noqa: E402
from drivers.modbus import ModbusOptions, ModbusSource  # noqa: E402
from drivers.serial_adc import SerialAdcSource, SerialOptions, frame_size  # noqa: E402
from observer.simulation.drive_stream import DriveStream  # noqa: E402
from tests.drivers.peers import FakeDrive  # noqa: E402


def _drain(src, seconds: float) -> tuple[int, float, float]:
    """Read for ``seconds``; (samples, wall s, process CPU s)."""
    n = 0
    src.read(timeout=5)  # opens; not timed
    c0, t0 = time.process_time(), time.monotonic()
    while time.monotonic() - t0 < seconds:
        block = src.read(timeout=0.2)
        if block is not None:
            n += len(block)
    return n, time.monotonic() - t0, time.process_time() - c0


def bench_serial(seconds: float, tmp: Path) -> None:
    wire = 921600 / (10 * frame_size(5))
    print(f"serial: 921600 baud carries at most {wire:.0f} frames/s of {frame_size(5)} bytes")
    for rate in (2000, 4388, 8000, 16000, 32000):
        link = tmp / f"tty-{rate}"
        fake = FakeDrive("serial", "--link", str(link), "--rate", str(rate), "--baud", "10000000")
        try:
            with SerialAdcSource(SerialOptions(port=str(link))) as src:
                n, wall, cpu = _drain(src, seconds)
                h = src.health()
        finally:
            fake.kill()
        ok = "sustained" if h["dropped"] == 0 and h["errors"] == 0 else "LOSSY"
        print(
            f"  offered {rate:6d} frames/s: received {n / wall:8.0f}/s, dropped {h['dropped']:6d}, "
            f"CPU {1000 * cpu / max(n, 1) * 1000:6.1f} ms per 1000 samples  [{ok}]"
        )


def bench_can(seconds: float) -> None:
    import can

    print("can (virtual bus, 2 frames per sample):")
    for rate in (1000, 2000, 4000, 8000, 16000):
        channel = f"bench-{os.getpid()}-{rate}"
        bus = can.Bus(interface="virtual", channel=channel)
        drive = CanFakeDrive(DriveStream(sample_rate_hz=rate), bus)
        drive.stream.prefetch()
        stop = threading.Event()
        sender_cpu = [0.0]

        def send(drive=drive, stop=stop, sender_cpu=sender_cpu) -> None:
            c0 = time.thread_time()
            drive.run(stop)
            sender_cpu[0] = time.thread_time() - c0

        with CanSource(interface="virtual", channel=channel) as src:
            src.read(timeout=0.5)
            thread = threading.Thread(target=send)
            thread.start()
            try:
                sent0 = drive.frames_sent
                n, wall, cpu = _drain(src, seconds)
                sent = (drive.frames_sent - sent0) / 2
            finally:
                stop.set()
                thread.join()
            h = src.health()
        bus.shutdown()
        consumer = max(cpu - sender_cpu[0], 0.0)
        if h["dropped"]:
            ok = "LOSSY"
        elif sent < 0.95 * rate * wall:
            ok = f"sender behind: sent only {sent / wall:.0f} samples/s"
        else:
            ok = "sustained"
        print(
            f"  offered {rate:6d} samples/s ({2 * rate} frames/s): received {n / wall:8.0f}/s, "
            f"dropped {h['dropped']}, consumer CPU {1e6 * consumer / max(n, 1):6.1f} ms "
            f"per 1000 samples  [{ok}]"
        )


def bench_modbus(seconds: float) -> None:
    fake = FakeDrive("modbus", "--port", "0", "--rate", "200")
    port = int(fake.line.split(" on ", 1)[1].split(",", 1)[0].rsplit(":", 1)[1])
    try:
        options = ModbusOptions(port=port, poll_rate_hz=10000.0)
        with ModbusSource(options) as src:
            src.read(timeout=5)
            p0, c0, t0 = src.health()["polls"], time.process_time(), time.monotonic()
            while time.monotonic() - t0 < seconds:
                src.read(timeout=0.2)
            wall, cpu = time.monotonic() - t0, time.process_time() - c0
            h = src.health()
    finally:
        fake.kill()
    polls = h["polls"] - p0
    print(
        f"modbus TCP (one 13-register read per poll): {polls / wall:.0f} polls/s, "
        f"timeouts {h['timeouts']}, client CPU {1e6 * cpu / max(polls, 1):.1f} ms per 1000 polls"
    )


def main() -> int:
    import tempfile

    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="measuring time per step")
    parser.add_argument("--only", choices=("serial", "can", "modbus"), default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.only in (None, "serial"):
            bench_serial(args.seconds, Path(tmp))
        if args.only in (None, "can"):
            bench_can(args.seconds)
        if args.only in (None, "modbus"):
            bench_modbus(args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
