"""Per-window accuracy and honesty of the estimator on converter-fed drives (a benchmark).

For every motor, sample rate, drive and seed: simulate a recording with the
project's converter simulator (``dcobserver simulate --preset realistic`` and
variants), decide each circuit's intersample model and relative delay on the
whole recording as the daemon does over its first windows, then estimate every
1 s window (hop 0.5 s) as the daemon would and compare with the truth:

- ``|z|``: median of ``|error / std|`` (an honest std gives ~0.67);
- ``ok``: share of windows the daemon's quality gate (``[observer.quality]``
  defaults) would publish as ``ok``;
- ``cov``: share of those within 2.5 std of the truth;
- ``tol``: share of those within the tolerance (Rf, Lf, K 1 %, Ra 2 %, La 5 %).

A window the daemon holds for its voltage reading (a chopper's pulses sampled in step,
:mod:`observer.estimation.linearity`: tested over the last 60 s every 10 s, and held until
the first result where no bridge made the voltage) is not ``ok``.

    python -m bench.window_honesty --seeds 3 --rates 2000,5000 --out docs/window_honesty.md

Takes ~20 s per recording on a quiet 2-core machine.
"""

from __future__ import annotations

import argparse
import functools
import sys
from dataclasses import dataclass
from typing import Any

import numpy as np

NAMES = ("Rf", "Lf", "Ra", "La", "K")
TOLERANCE = np.array([0.01, 0.01, 0.02, 0.05, 0.01])


@dataclass(frozen=True)
class Case:
    motor: str
    rate: int
    drive: str
    seed: int


#: ``thyristor-`` and a variant of :data:`bench.accuracy_rates.VARIANTS`: the thyristor drive on
#: 60 Hz mains, with commutation overlap, behind a multiplexed ADC, ...
VARIANT_PREFIX = "thyristor-"


def _drive(name: str, rate: float = 2000.0):  # type: ignore[no-untyped-def]
    """A drive of :mod:`bench.accuracy_rates`, or its thyristor drive behind another chain
    (``rate``: the sample rate, for variants that depend on it)."""
    from bench.accuracy_rates import VARIANTS, drive_spec
    from observer.simulation.chain import ChannelChain, MeasurementChain
    from observer.simulation.converter import REALISTIC_CHANNEL

    if name == "realistic":
        return drive_spec("thyristor")
    if name == "chopper":
        return drive_spec("chopper")
    if name == "chopper-averaged-voltages":
        # The chopper's voltages measured as their means over each period (an integrating
        # ADC): what the aliased carrier leaves in an instantaneous sample is gone.
        chain = MeasurementChain.uniform(REALISTIC_CHANNEL)
        for ch in ("va", "vf"):
            chain = chain.with_channel(ch, averaging=True)
        return drive_spec("chopper").replace(chain=chain)
    if name == "chopper-rc-voltages":
        # The chopper behind RC voltage filters at fs/4 beside the Butterworth currents.
        chain = MeasurementChain.uniform(REALISTIC_CHANNEL)
        for ch in ("va", "vf"):
            chain = chain.with_channel(ch, filter="rc", order=1)
        return drive_spec("chopper").replace(chain=chain)
    if name == "no-filter":
        return drive_spec("thyristor").replace(
            chain=MeasurementChain.uniform(ChannelChain(bits=12))
        )
    if name == "rc1-voltages":
        chain = MeasurementChain.uniform(REALISTIC_CHANNEL)
        for ch in ("va", "vf"):
            chain = chain.with_channel(ch, filter="rc", order=1)
        return drive_spec("thyristor").replace(chain=chain)
    # Front ends the estimator was never tuned on (issue 10 section 3: other chains), one
    # kind on both windings' current or voltage channels, the rest as ``realistic``.
    others = {
        "rc1-currents": ("currents", dict(filter="rc", order=1)),
        "bessel4-currents": ("currents", dict(filter="bessel", order=4)),
        "butter4-fs3-currents": ("currents", dict(filter="butter", order=4, cutoff_per_fs=1 / 3)),
        "bessel2-voltages": ("voltages", dict(filter="bessel", order=2)),
        "fs8-voltages": ("voltages", dict(cutoff_per_fs=0.125)),
        "rc1-fs8-voltages": ("voltages", dict(filter="rc", order=1, cutoff_per_fs=0.125)),
    }
    if name in others:
        which, change = others[name]
        chain = MeasurementChain.uniform(REALISTIC_CHANNEL)
        for ch in ("ia", "if") if which == "currents" else ("va", "vf"):
            chain = chain.with_channel(ch, **change)
        return drive_spec("thyristor").replace(chain=chain)
    variant = name.removeprefix(VARIANT_PREFIX)
    if name.startswith(VARIANT_PREFIX) and variant in VARIANTS:
        return VARIANTS[variant][1](drive_spec("thyristor"), rate)
    if name == "bare-voltages":
        chain = MeasurementChain.uniform(REALISTIC_CHANNEL)
        for ch in ("va", "vf"):
            chain = chain.with_channel(ch, filter="none", order=0)
        return drive_spec("thyristor").replace(chain=chain)
    raise SystemExit(f"unknown drive {name!r}")


def _daemon_holds(
    sig: dict[str, np.ndarray], dt: float, win: int, hop: int, armature_model: str
) -> list[tuple[bool, bool, Any]]:
    """Per window, whether the daemon holds (field, armature) for its voltage reading's
    linearity (:mod:`observer.estimation.linearity`): tested over the last
    ``WATCH_SECONDS`` every ``RETEST_SECONDS``, the result used 1.5 s later (the daemon's
    ``FILTER_DUE_S``), and before the first result a measured voltage no bridge made held;
    and the fold the daemon takes out of the window's armature voltage (or None).

    The daemon reads the armature's voltage as measured by the window's own model, its first
    window's, or most earlier windows' (``WindowObserver._armature_measured``). Here every
    window has the whole recording's model, so all three are ``armature_model``."""
    from observer.estimation.linearity import (
        RETEST_SECONDS,
        WATCH_SECONDS,
        applies_to,
        field_note,
        made_by_a_bridge,
        voltage_linearity,
    )

    n = sig["va"].shape[0]
    tests = []  # (window end from which used, result)
    for k in range(1, int(n * dt / RETEST_SECONDS) + 1):
        end = int(round(k * RETEST_SECONDS / dt))
        part = slice(max(0, end - int(round(WATCH_SECONDS / dt))), end)
        result = voltage_linearity(
            sig["va"][part], sig["ia"][part], dt, sig["if"][part], sig["omega"][part]
        )
        if result is not None:
            tests.append((end + int(round(1.5 / dt)), result))
    # The daemon stops the test for good once a window shows a bridge's ripple.
    bridge = made_by_a_bridge(sig["va"][:win], dt, winding="armature")
    out = []
    for start in range(0, n - win + 1, hop):
        end = start + win
        s = slice(start, end)
        known = [r for due, r in tests if due <= end]
        result = known[-1] if known else None
        if bridge or not applies_to(armature_model):
            out.append((False, False, None))
        elif result is None:
            measured = armature_model == "smooth" and not made_by_a_bridge(
                sig["va"][s], dt, winding="armature"
            )
            out.append(
                (
                    measured and not made_by_a_bridge(sig["vf"][s], dt, winding="field"),
                    measured,
                    None,
                )
            )
        else:
            held = (bool(field_note(result, sig["vf"][s], dt)), not result.linear)
            out.append((*held, result.correction))
    return out


def run_case(
    case: Case,
    duration_s: float = 30.0,
    configured: bool = False,
    va_offset: float = 0.0,
    identify: bool = True,
) -> dict[str, np.ndarray]:
    """Errors, stds and the quality flag of every window of one recording; ``configured``:
    the estimator is told the chain's front ends (``[chain]``), as a user who knows them;
    ``va_offset``: the armature voltage sensor's offset (V), which no estimator is told."""
    from bench.accuracy_rates import PARAMETERS
    from observer.config import QualityConfig
    from observer.estimation import estimate_armature, estimate_field
    from observer.estimation.motor import MOTORS
    from observer.simulation.converter_drive import simulate_converter

    motor = MOTORS[case.motor]
    from observer.estimation.estimate import (
        untold_filter,
        with_field_fold,
        with_learned_mismatch,
    )
    from observer.estimation.frontend import winding_front_ends

    drive = _drive(case.drive, case.rate)
    if va_offset:
        drive = drive.replace(chain=drive.chain.with_channel("va", offset=va_offset))
    chain = drive.chain.to_config() if configured else None
    fe = {w: winding_front_ends(chain, w) for w in ("field", "armature")}
    rec, _ = simulate_converter(
        motor, drive, duration_s=duration_s, sample_rate_hz=case.rate,
        noise=0.002, seed=case.seed,
    )  # fmt: skip
    sig = {c: np.asarray(rec[c], dtype=float) for c in ("va", "ia", "vf", "if", "omega")}
    dt = 1.0 / case.rate
    # Untold: the voltages' filters identified from the converter's jumps, as `dcobserver
    # estimate` does from the whole recording (the daemon from a window once the chain is
    # decided); ``--no-filter-id``: the weakest filter in use assumed, as before.
    told = {
        w: untold_filter(rec, w, {"front_ends": fe[w]})[1] if identify else {}
        for w in ("field", "armature")
    }
    kw = dict(n_particles=40, max_iterations=40, rng=0)
    whole_f = estimate_field(
        sig["vf"], sig["if"], dt, front_ends=fe["field"], **told["field"], **kw
    )
    whole_a = estimate_armature(
        sig["va"], sig["ia"], sig["if"], sig["omega"], dt, front_ends=fe["armature"],
        **told["armature"], **kw,
    )  # fmt: skip
    # Untold channels that differ like the commonest pair: learned and corrected for, as
    # `dcobserver estimate` does (the daemon learns it over its first windows).
    learned = {"field": whole_f.mismatch_size, "armature": whole_a.mismatch_size}
    whole_f = with_learned_mismatch(
        whole_f,
        functools.partial(estimate_field, sig["vf"], sig["if"], dt, **told["field"], **kw),
    )
    whole_a = with_learned_mismatch(
        whole_a,
        functools.partial(
            estimate_armature,
            sig["va"],
            sig["ia"],
            sig["if"],
            sig["omega"],
            dt,
            **told["armature"],
            **kw,
        ),
    )
    truth = np.array([getattr(motor, PARAMETERS[name][2]) for name in NAMES])
    quality = QualityConfig()
    limit = np.array([*quality.limits("field").values(), *quality.limits("armature").values()])
    n = sig["va"].shape[0]
    win, hop = case.rate, case.rate // 2
    held = _daemon_holds(sig, dt, win, hop, whole_a.intersample)
    rows = []
    for i, start in enumerate(range(0, n - win + 1, hop)):
        s = slice(start, start + win)
        kw_w = dict(n_particles=40, max_iterations=40, rng=i, fit_shift=False)
        fold = held[i][2]
        va = sig["va"][s] if fold is None else sig["va"][s] - fold.of_samples(sig["va"][s], dt)
        f = estimate_field(
            sig["vf"][s], sig["if"][s], dt, intersample=whole_f.intersample,
            shift=whole_f.shift_samples, front_ends=fe["field"], mismatch=learned["field"],
            **told["field"], **kw_w,
        )  # fmt: skip
        f = with_field_fold(f, fold, sig["vf"][s], dt)
        a = estimate_armature(
            va, sig["ia"][s], sig["if"][s], sig["omega"][s], dt,
            intersample=whole_a.intersample, shift=whole_a.shift_samples,
            front_ends=fe["armature"], mismatch=learned["armature"],
            **told["armature"], **kw_w,
        )  # fmt: skip
        est = np.array([f.resistance_ohm, f.inductance_h, a.resistance_ohm, a.inductance_h,
                        a.emf_constant_h])  # fmt: skip
        std = np.array([f.std["R"], f.std["L"], a.std["R"], a.std["L"], a.std["K"]])
        described = np.array([f.describes_window] * 2 + [a.describes_window] * 3)
        described &= ~np.array([held[i][0]] * 2 + [held[i][1]] * 3)
        rows.append((est, std, described))
    est = np.array([r[0] for r in rows])
    std = np.array([r[1] for r in rows])
    described = np.array([r[2] for r in rows])
    return {
        "err": est / truth - 1.0,
        "z": (est - truth) / std,
        # what the daemon publishes: a window its model describes, within the quality limits
        "ok": (std / np.abs(est) <= limit) & described,
    }


def summarise(results: list[dict[str, np.ndarray]]) -> dict[str, tuple[float, float, float, float]]:
    err = np.concatenate([r["err"] for r in results])
    z = np.concatenate([r["z"] for r in results])
    ok = np.concatenate([r["ok"] for r in results])
    out = {}
    for j, name in enumerate(NAMES):
        o = ok[:, j]
        cov = float(np.mean(np.abs(z[o, j]) < 2.5)) if o.any() else float("nan")
        tol = float(np.mean(np.abs(err[o, j]) < TOLERANCE[j])) if o.any() else float("nan")
        out[name] = (float(np.median(np.abs(z[:, j]))), float(o.mean()), cov, tol)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.window_honesty",
        description=__doc__.split("\n\n")[0] if __doc__ else None,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--motors", default="p12,industrial-440v", help="motors (observer MOTORS)")
    parser.add_argument("--rates", default="2000,5000,10000", help="sample rates (Hz)")
    parser.add_argument(
        "--drives", default="realistic,no-filter,chopper,rc1-voltages,bare-voltages",
        help="drives: realistic, no-filter, chopper, rc1-voltages, bare-voltages, and front "
        "ends not tuned on: rc1-currents, bessel4-currents, butter4-fs3-currents, "
        "bessel2-voltages, fs8-voltages, rc1-fs8-voltages; chopper-averaged-voltages (the "
        "chopper with its voltages measured as means over each period), chopper-rc-voltages "
        "(behind RC voltage filters at fs/4); thyristor-VARIANT "
        "for a variant of bench.accuracy_rates (thyristor-60hz, thyristor-overlap, "
        "thyristor-skew, thyristor-16bit, thyristor-bessel4, thyristor-butter4-v)",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, default=3, help="recordings per case")
    parser.add_argument("--duration", type=float, default=30.0, help="recording length (s)")
    parser.add_argument(
        "--configured", action="store_true",
        help="tell the estimator the chain's front ends (as [chain] would); default: untold",
    )  # fmt: skip
    parser.add_argument(
        "--va-offset", type=float, default=0.0,
        help="armature voltage sensor offset (V) in the recordings, not told to the estimator",
    )  # fmt: skip
    parser.add_argument(
        "--no-filter-id", action="store_true",
        help="untold: assume the weakest voltage filter in use instead of identifying it from "
        "the converter's jumps (the estimator before filter identification)",
    )  # fmt: skip
    parser.add_argument("--out", help="also write the table to this Markdown file")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    from tqdm import tqdm

    cases = [
        (m, int(r), d)
        for m in args.motors.split(",")
        for r in args.rates.split(",")
        for d in args.drives.split(",")
    ]
    lines = [
        "| motor | rate | drive | " + " | ".join(f"{n} \\|z\\| ok cov tol" for n in NAMES) + " |",
        "|---|---|---|" + "---|" * len(NAMES),
    ]
    bar = tqdm(total=len(cases) * args.seeds, disable=args.quiet, unit="rec", file=sys.stderr)
    for motor, rate, drive in cases:
        results = []
        for seed in range(args.seeds):
            bar.set_description(f"{motor} {rate} Hz {drive} seed {seed}")
            results.append(
                run_case(
                    Case(motor, rate, drive, seed),
                    args.duration,
                    args.configured,
                    args.va_offset,
                    identify=not args.no_filter_id,
                )
            )
            bar.update()
        summary = summarise(results)
        cells = [
            "{:.2f} {:.2f} {:.2f} {:.2f}".format(*summary[n]).replace("nan", "-") for n in NAMES
        ]
        lines.append(f"| {motor} | {rate} | {drive} | " + " | ".join(cells) + " |")
        tqdm.write(lines[-1], file=sys.stdout)
    bar.close()
    table = "\n".join(lines)
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(
                f"Per-window honesty, {args.seeds} seeds x {args.duration:g} s "
                f"(`python -m bench.window_honesty --seeds {args.seeds}`)\n\n{table}\n"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
