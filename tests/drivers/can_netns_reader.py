"""Run inside a network namespace by test_can_bus: read a CAN fake drive over udp_multicast.

Usage: python can_netns_reader.py GROUP N_SAMPLES OUT.csv -- FAKE-DRIVE ARGS...
Subscribes first, then starts ``dcobserver fake-drive can`` (another process, the
same namespace), writes the longest gap-free run of N_SAMPLES samples as a
recording and prints the source's health as one JSON line.
"""

from __future__ import annotations

import json
import subprocess
import sys

from drivers.can_bus import CanSource
from observer.recording import write_recording
from tests.drivers.peers import collect, to_recording


def main() -> int:
    group, n, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    fake_args = sys.argv[sys.argv.index("--") + 1 :]
    # The fake drive starts after the subscription and may take seconds to import and
    # simulate its first chunk on a loaded machine: staleness is not what this tests.
    with CanSource(interface="udp_multicast", channel=group, stale_timeout_s=30.0) as src:
        src.read(timeout=0.1)  # the pump opens the bus: subscribed before the drive starts
        if not src.wait_connected(10):
            raise SystemExit("could not open the udp_multicast bus")
        fake = subprocess.Popen(
            [sys.executable, "-m", "observer.cli", "fake-drive", "can", *fake_args],
            stdout=subprocess.DEVNULL,
        )
        try:
            blocks = collect(src, n, timeout=30)
        finally:
            fake.kill()
            fake.wait()
        health = src.health()
    write_recording(to_recording(blocks, 1000.0), out)
    print(json.dumps(health), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
