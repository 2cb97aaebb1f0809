"""Armature window fits with the speed as measured and from the shaft's equation (a benchmark).

The drive's speed loop is closed on the noisy tachometer, so where the drive
holds its speed the only variation of ``va`` and ``ia`` is its answer to that
noise (:mod:`observer.estimation.mechanics`). For every rate and seed: a 60 s
P-12 recording of ``dcobserver simulate`` (0.2 % sensor noise; ``--preset``:
the ideal drive, or the converter-fed chain), every 1 s window from 15 s on
estimated as ``estimate_armature`` does, once with ``fit_speed=False`` (the
samples as measured, as before 2026-11-27) and once with the default (the
shaft's fit); per parameter the median and largest |error| (%) and |error /
std| (an honest std gives a median of about 0.67).

    python -m bench.held_speed --rates 2000,5000,10000 --seeds 1,2
    python -m bench.held_speed --rates 10000 --seeds 1 --preset realistic

Takes ~10-40 s per recording on a quiet 2-core machine.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

from bench.common import machine_description
from observer.estimation import estimate_armature
from observer.estimation.motor import P12
from observer.simulation.converter import PRESETS
from observer.simulation.simulate import simulate

TRUTH = {"R": P12.armature_resistance_ohm, "L": P12.armature_inductance_h, "K": P12.emf_constant_h}


def run(rate: float, seed: int, preset: str, duration_s: float) -> dict[str, np.ndarray]:
    """``{"measured"|"shaft": (windows, 3 parameters, (error, z))}``."""
    drive = {} if preset == "ideal" else {"drive": PRESETS[preset], "drive_name": preset}
    rec = simulate(P12, duration_s=duration_s, sample_rate_hz=rate, noise=0.002, seed=seed,
                   **drive)  # fmt: skip
    t = np.asarray(rec.t)
    model = "hold" if preset == "ideal" else "auto"
    out: dict[str, list[list[tuple[float, float]]]] = {"measured": [], "shaft": []}
    for t0 in np.arange(15.0, duration_s - 1.0, 1.0):
        m = (t >= t0) & (t < t0 + 1.0)
        s = {c: np.asarray(rec[c], dtype=float)[m] for c in ("va", "ia", "if", "omega")}
        for name, fit_speed in (("measured", False), ("shaft", True)):
            est = estimate_armature(
                s["va"], s["ia"], s["if"], s["omega"], 1.0 / rate, rng=0, intersample=model,
                fit_speed=fit_speed,
            )  # fmt: skip
            value = {"R": est.resistance_ohm, "L": est.inductance_h, "K": est.emf_constant_h}
            out[name].append(
                [(value[p] / TRUTH[p] - 1.0, (value[p] - TRUTH[p]) / est.std[p]) for p in TRUTH]
            )
    return {k: np.abs(np.array(v)) for k, v in out.items()}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rates", default="2000,5000,10000", help="sample rates (Hz), comma-separated")
    p.add_argument("--seeds", default="1,2", help="simulation seeds, comma-separated")
    p.add_argument("--preset", default="ideal", choices=sorted(PRESETS))
    p.add_argument("--duration", type=float, default=60.0, help="recording length (s)")
    return p.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"{machine_description()}; preset {args.preset}, {args.duration:g} s recordings")
    print()
    print("| rate | seed | speed | windows | Ra \\|err\\| % med / max | Ra \\|z\\| med / max "
          "| La \\|err\\| % med / max | La \\|z\\| med / max | K \\|err\\| % med / max "
          "| K \\|z\\| med / max |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    jobs = [(r, s) for r in rates for s in seeds]
    for rate, seed in tqdm(jobs, desc="recordings", file=sys.stderr):
        res = run(rate, seed, args.preset, args.duration)
        for name, a in res.items():
            cells = []
            for j in range(3):
                err, z = a[:, j, 0] * 100.0, a[:, j, 1]
                cells.append(f"{np.median(err):.2f} / {err.max():.1f}")
                cells.append(f"{np.median(z):.2f} / {z.max():.1f}")
            tqdm.write(f"| {rate:g} | {seed} | {name} | {a.shape[0]} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
