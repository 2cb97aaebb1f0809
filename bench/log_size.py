"""Bytes per sample of the daemon's log: the JSON blocks of before against the protobuf blocks now.

Data: a simulated P-12 at 10 kHz, five channels (va, ia, vf, if, omega), 0.2 % sensor noise,
once as float64 ("noisy float") and once as a 12-bit drive ADC measures it, +-2.5x rated
(``observer.recording.quantise``, "adc" metadata: the log stores counts). For each it writes

* **before**: the JSON sample blocks the daemon logged until issue 13 (0.1 s per message,
  ZSTD chunks), and
* **after**: the daemon's log as it is written now: :class:`observer.service.mcaplog.McapLog`
  fed in real time (0.05 s blocks, flushed every ``flush_s``), estimates and health off,

and prints file bytes per sample (metadata and index included). Samples only: the estimates
and health the daemon also logs add ~1 kB/s.

Usage::

    python -m bench.log_size [--duration S] [--rate HZ] [--bits N]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import adc_full_scale, machine_description  # noqa: E402
from observer.config import LogConfig  # noqa: E402
from observer.estimation.motor import P12  # noqa: E402
from observer.recording import AdcScale, Recording, adc_scales, quantise, write_mcap  # noqa: E402
from observer.service.mcaplog import McapLog  # noqa: E402
from observer.simulation.simulate import simulate  # noqa: E402


def _live_log_bytes(rec: Recording, folder: Path, pace: bool) -> int:
    """Size of the daemon's log of ``rec``, fed as the daemon feeds it (0.05 s blocks)."""
    scales = {c: AdcScale(*s) for c, s in adc_scales(rec.metadata).items()}
    log = McapLog(LogConfig(dir=str(folder)), "bench")
    log.start()
    t_ns = np.rint(rec.t * 1e9).astype(np.int64)
    step = max(1, round(0.05 / rec.dt))
    start = time.monotonic()
    for i in range(0, rec.n_samples, step):
        sl = slice(i, i + step)
        if pace:  # real time: the writer flushes every flush_s as it does live
            wait = start + rec.t[sl][0] - rec.t[0] - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        log.submit_samples(t_ns[sl], {c: rec[c][sl] for c in rec.channels}, scales=scales)
    log.close()
    assert log.health()["dropped"] == 0, log.health()
    return sum(f.stat().st_size for f in folder.glob("*.mcap"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="recording length (s)")
    parser.add_argument("--rate", type=float, default=10_000.0, help="sample rate (Hz)")
    parser.add_argument("--bits", type=int, default=12, help="ADC resolution")
    parser.add_argument("--no-pace", action="store_true", help="feed the log as fast as it goes")
    args = parser.parse_args()

    noisy = simulate(P12, duration_s=args.duration, sample_rate_hz=args.rate, noise=0.002, seed=3)
    adc = quantise(noisy, adc_full_scale(P12), bits=args.bits)
    n = noisy.n_samples
    rows = []
    with tempfile.TemporaryDirectory(prefix="dcobserver-log-size-") as tmp:
        folder = Path(tmp)
        for label, rec in (("noisy float64", noisy), (f"{args.bits}-bit ADC counts", adc)):
            before = folder / f"before-{len(rows)}.mcap"
            write_mcap(rec, before, block_s=0.1, encoding="json")
            after = _live_log_bytes(rec, folder / f"after-{len(rows)}", pace=not args.no_pace)
            rows.append((label, before.stat().st_size / n, after / n))
    print(f"# Log size, {args.rate:g} Hz x 5 channels, {args.duration:g} s, P-12 0.2 % noise")
    print(f"# {machine_description()}")
    print("| samples | before: JSON blocks (B/sample) | after: daemon log (B/sample) | ratio |")
    print("|---|---|---|---|")
    for label, before_b, after_b in rows:
        print(f"| {label} | {before_b:.1f} | {after_b:.1f} | {before_b / after_b:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
