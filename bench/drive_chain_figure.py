"""The figure of docs/drive_chain.md: what the realistic drive's waveforms look like at 50 kHz.

A P-12 on the dual 6-pulse thyristor bridge and the single-phase field bridge (50 Hz mains),
recorded at 50 kHz without filter, ADC or noise: the armature voltage and current under load
(6-pulse ripple), at light load (discontinuous conduction: the terminals show the back-EMF while
the current is zero) and around a bridge changeover (zero current for the dead time, then the
other bridge), and the field's voltage and current (100 Hz ripple, negative segments).

    python -m bench.drive_chain_figure [--out docs/drive_chain.png]   # about 30 s
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv: list[str] | None = None) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from observer.estimation.motor import P12
    from observer.simulation.chain import MeasurementChain
    from observer.simulation.converter import ConverterSpec, DriveSpec
    from observer.simulation.converter_drive import simulate_converter

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/drive_chain.png")
    parser.add_argument("--seed", type=int, default=4)
    args = parser.parse_args(argv)

    fs = 50_000.0
    drive = DriveSpec(ConverterSpec("thyristor-6p", "bridge-1p"), MeasurementChain())
    rec, truth = simulate_converter(
        P12, drive, duration_s=12.0, sample_rate_hz=fs, noise=0.0, seed=args.seed,
        want_truth=True,
    )  # fmt: skip
    assert truth is not None
    t = rec.t
    span = int(0.04 * fs)  # 40 ms: two mains periods
    ia_avg = np.convolve(np.abs(truth.ia), np.ones(span) / span, mode="same")
    blocked = np.convolve((truth.conducting == 0).astype(float), np.ones(span) / span, "same")
    heavy = int(np.argmax(np.where(blocked == 0, ia_avg, 0)))
    light = int(np.argmax(np.where(ia_avg > 0.1 * P12.rated_armature_current_a, blocked, 0)))
    change = int(np.flatnonzero(np.diff(truth.bridge) != 0)[0]) + 1
    windows = [
        (heavy, "under load: 6-pulse ripple (300 Hz), a jump at every firing"),
        (light, "light load: discontinuous conduction, va = back-EMF while ia = 0"),
        (change, "bridge changeover: ia = 0 for the dead time, then the other bridge"),
    ]
    fig, axes = plt.subplots(4, 1, figsize=(10, 11))
    for ax, (centre, title) in zip(axes[:3], windows, strict=True):
        w = slice(max(centre - span // 2, 0), centre + span // 2)
        tw = (t[w] - t[w][0]) * 1e3
        ax.plot(tw, rec["va"][w], lw=0.8, color="tab:blue", label="va (V)")
        ax.plot(tw, truth.emf[w], lw=0.8, ls="--", color="tab:gray", label="back-EMF (V)")
        ax.set_ylabel("V")
        ax2 = ax.twinx()
        ax2.plot(tw, rec["ia"][w], lw=1.0, color="tab:red", label="ia (A)")
        if centre == change:
            ax2.plot(tw, truth.bridge[w] * P12.rated_armature_current_a, lw=0.8,
                     color="tab:green", label="bridge (+-Ia_rated)")  # fmt: skip
        ax2.set_ylabel("A")
        ax.set_title(f"armature, t = {t[w][0]:.2f} s: {title}", fontsize=10)
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], loc="upper right", fontsize=8)
    w = slice(heavy - span // 2, heavy + span // 2)
    tw = (t[w] - t[w][0]) * 1e3
    ax = axes[3]
    ax.plot(tw, rec["vf"][w], lw=0.8, color="tab:blue", label="vf (V)")
    ax.set_ylabel("V")
    ax2 = ax.twinx()
    ax2.plot(tw, rec["if"][w], lw=1.0, color="tab:red", label="if (A)")
    ax2.set_ylabel("A")
    ax.set_title("field, single-phase bridge: 100 Hz ripple, negative segments", fontsize=10)
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [ln.get_label() for ln in lines], loc="upper right", fontsize=8)
    axes[3].set_xlabel("ms")
    fig.suptitle(
        "P-12 on a dual 6-pulse thyristor bridge and a 1-phase field bridge, 50 Hz mains, "
        "sampled at 50 kHz\n(python -m bench.drive_chain_figure)", fontsize=11,
    )  # fmt: skip
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
