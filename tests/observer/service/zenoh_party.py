"""A party on a dcobserver Zenoh network, in its own process, for the security tests.

    python zenoh_party.py CONFIG.toml MODE [--sub KEYEXPR] [--put KEY=TAG ...]

opens a session from CONFIG.toml's ``[zenoh]`` table exactly as dcobserver does
(:mod:`observer.service.zenohconf`), prints ``open`` (or ``refused: ...`` and
exits 3), then puts ``TAG <n>`` on every KEY each 10 ms (to other sessions
only), printing ``put <n>`` every 10 rounds, and prints ``got <key> <payload>``
for every sample received on KEYEXPR. It runs until killed.
"""

from __future__ import annotations

import argparse
import queue
import sys
import time

import zenoh

from observer.config import ZenohFileConfig, load_config
from observer.service.zenohconf import session_json


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("config")
    parser.add_argument("mode", choices=("peer", "client"))
    parser.add_argument("--sub", default=None)
    parser.add_argument("--put", action="append", default=[])
    args = parser.parse_args()
    link = load_config(args.config, ZenohFileConfig).zenoh
    try:
        session = zenoh.open(zenoh.Config.from_json5(session_json(link, args.mode)))
    except Exception as exc:
        print(f"refused: {str(exc).splitlines()[0]}", flush=True)
        return 3
    print("open", flush=True)
    received: queue.SimpleQueue[str] = queue.SimpleQueue()
    if args.sub:
        session.declare_subscriber(
            args.sub, lambda s: received.put(f"got {s.key_expr} {s.payload.to_string()}")
        )
        print("declared", flush=True)
    publishers = []
    for spec in args.put:
        key, _, tag = spec.partition("=")
        # Only to others: what a party receives must have come through the network.
        remote = zenoh.Locality.REMOTE
        publishers.append((session.declare_publisher(key, allowed_destination=remote), tag))
    n = 0
    while True:
        for publisher, tag in publishers:
            publisher.put(f"{tag} {n}")
        if publishers and n % 10 == 0:
            print(f"put {n}", flush=True)
        n += 1
        deadline = time.monotonic() + 0.01
        while (left := deadline - time.monotonic()) > 0:
            try:
                print(received.get(timeout=left), flush=True)
            except queue.Empty:
                break


if __name__ == "__main__":
    sys.exit(main())
