"""How honest the daemon's window fits are on a recording of a known motor (a benchmark).

Reads the JSON lines of ``dcobserver replay --json`` (every window's raw fit, its
relative std and the tracker's quality) and scores each parameter against the
motor's true values, over the windows after ``--after`` seconds:

- ``|z|``: median of ``|error / std|`` over all windows (an honest std gives ~0.67);
- ``ok``: share of windows the quality gate published as ``ok``;
- ``cov``: share of those within 2.5 std of the truth (issue 10: >= 95 %);
- ``tol``: share of those within the tolerance (Rf, Lf, K 1 %, Ra 2 %, La 5 %).

    dcobserver simulate mixed.mcap --duration 30 --rate 5000 --seed 3 \\
        --aa-filter 'butter2@fs/4,va=rc1@fs/4,vf=rc1@fs/4'
    dcobserver replay --json --no-progress mixed.mcap > mixed.jsonl
    python -m bench.replay_honesty mixed.jsonl --motor p12
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from bench.accuracy_rates import PARAMETERS
from bench.window_honesty import NAMES, TOLERANCE

#: Parameter -> the issue's tolerance (relative).
TOLERANCES = dict(zip(NAMES, (float(t) for t in TOLERANCE), strict=True))


def score(lines: list[dict], truth: dict[str, float], after_s: float) -> dict[str, dict]:
    """Per parameter: median |z|, and the ok share with its coverage and tolerance shares."""
    rows = [r for r in lines if "armature" in r and r["t_ns"] / 1e9 >= after_s]
    out: dict[str, dict] = {}
    for name, (circuit, key, _) in PARAMETERS.items():
        tol = TOLERANCES[name]
        raw = np.array([_num(r[circuit]["raw"].get(key)) for r in rows])
        rel = np.array([_num(r[circuit]["rel_std"].get(key)) for r in rows])
        ok = np.array([r[circuit]["quality"].get(key) == "ok" for r in rows], dtype=bool)
        err = raw / truth[name] - 1.0
        z = np.abs(err / rel)
        finite = np.isfinite(z)
        out[name] = {
            "windows": len(rows),
            "median_abs_z": float(np.median(z[finite])) if finite.any() else float("nan"),
            "ok": float(ok.mean()) if rows else float("nan"),
            "cov": float(np.mean(z[ok] < 2.5)) if ok.any() else float("nan"),
            "tol": float(np.mean(np.abs(err[ok]) < tol)) if ok.any() else float("nan"),
            "median_error_pct": float(100 * np.nanmedian(err)) if rows else float("nan"),
        }
    return out


def _num(x: object) -> float:
    return float(x) if isinstance(x, (int, float)) else float("nan")


def table(result: dict[str, dict]) -> str:
    head = (
        "| parameter | windows | median error % | median \\|z\\| | ok | within 2.5 std "
        "| within tol |"
    )
    lines = [head, "|---|---|---|---|---|---|---|"]
    for name, s in result.items():
        lines.append(
            f"| {name} | {s['windows']} | {s['median_error_pct']:+.2f} | {s['median_abs_z']:.2f} "
            f"| {s['ok']:.2f} | {s['cov']:.2f} | {s['tol']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from observer.estimation.motor import MOTORS

    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("jsonl", type=Path, help="output of dcobserver replay --json")
    ap.add_argument("--motor", default="p12", choices=sorted(MOTORS), help="true motor")
    ap.add_argument("--after", type=float, default=2.0, help="skip windows ending before (s)")
    args = ap.parse_args(argv)
    try:
        text = args.jsonl.read_text()
    except OSError as exc:
        print(f"replay_honesty: cannot read {args.jsonl}: {exc.strerror}", file=sys.stderr)
        return 2
    lines = []
    for n, line in enumerate(text.splitlines(), 1):
        try:
            lines.append(json.loads(line))
        except json.JSONDecodeError:
            print(f"replay_honesty: {args.jsonl}:{n} is not JSON", file=sys.stderr)
            return 2
    motor = MOTORS[args.motor]
    truth = {name: float(getattr(motor, spec[2])) for name, spec in PARAMETERS.items()}
    print(table(score(lines, truth, args.after)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
