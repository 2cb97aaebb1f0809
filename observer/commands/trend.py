"""The trend report of ``dcobserver replay --report/--png``: what the observer saw over time.

Not a command (it is not in :data:`observer.cli.COMMANDS`). One figure, what a
drive engineer looks at first: each parameter (Rf, Lf, Ra, La, K) over time,
each window's estimate with its one-sigma band and quality (held and
not-identified windows marked), the value the observer reports as a line,
windows skipped or failed shaded; below them the windings' currents and the
speed. ``--report`` writes it in one self-contained HTML page with a summary
table, ``--png`` as an image.
"""

from __future__ import annotations

import html
import io
import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: (circuit, parameter, label, SI unit) of each parameter row, top to bottom.
PARAMETERS: tuple[tuple[str, str, str, str], ...] = (
    ("field", "R", "Rf", "ohm"),
    ("field", "L", "Lf", "H"),
    ("armature", "R", "Ra", "ohm"),
    ("armature", "L", "La", "H"),
    ("armature", "K", "K", "H"),
)
#: quality -> (matplotlib colour, marker); others are drawn as "other".
QUALITY_STYLE: dict[str, tuple[str, str]] = {
    "ok": ("tab:green", "o"),
    "held": ("tab:orange", "s"),
    "none": ("0.6", "x"),
    "other": ("tab:purple", "^"),
}


@dataclass
class Trend:
    """What a replay produced, gathered for the report.

    Attributes
    ----------
    windows : list of (t_s, estimate dict or None, skip reason)
        One entry per window, ``t_s`` its end relative to the first sample.
    blocks : dict
        Channel -> list of (t_s, min, max) per source block: the envelope of
        each signal, small enough for hours of log.
    """

    windows: list[tuple[float, dict[str, Any] | None, str]] = field(default_factory=list)
    blocks: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)
    t0_ns: int | None = None

    def add_block(self, t_ns: np.ndarray, signals: Any) -> None:
        """Add one block of samples (``t_ns`` int64 ns, channel -> array, SI)."""
        if t_ns.size == 0:
            return
        if self.t0_ns is None:
            self.t0_ns = int(t_ns[0])
        t_mid = (float(t_ns[t_ns.size // 2]) - self.t0_ns) / 1e9
        for name, x in signals.items():
            finite = x[np.isfinite(x)]
            if finite.size:
                entry = (t_mid, float(finite.min()), float(finite.max()))
                self.blocks.setdefault(name, []).append(entry)

    def add_window(self, t1_ns: int, estimate: dict[str, Any] | None, skip_reason: str) -> None:
        """Add one window's outcome (an estimate, or why it was skipped)."""
        if self.t0_ns is None:
            self.t0_ns = int(t1_ns)
        self.windows.append(((t1_ns - self.t0_ns) / 1e9, estimate, skip_reason))

    # ------------------------------------------------------------------ per parameter

    def series(self, circuit: str, p: str) -> dict[str, np.ndarray]:
        """Arrays over the estimated windows: t, raw value, std, reported value, quality."""
        t, raw, std, value, quality = [], [], [], [], []
        for t_s, e, _ in self.windows:
            c = (e or {}).get(circuit)
            if not c or p not in (c.get("quality") or {}):
                continue
            v = c.get(p)
            r = (c.get("raw") or {}).get(p, v)
            s = (c.get("std") or {}).get(p)
            rel = (c.get("rel_std") or {}).get(p)
            if s is None and rel is not None and r is not None:
                s = rel * abs(r)
            t.append(t_s)
            raw.append(math.nan if r is None else r)
            std.append(math.nan if s is None else s)
            value.append(math.nan if v is None else v)
            quality.append(str(c["quality"][p]))
        return {
            "t": np.array(t, dtype=float),
            "raw": np.array(raw, dtype=float),
            "std": np.array(std, dtype=float),
            "value": np.array(value, dtype=float),
            "quality": np.array(quality, dtype=object),
        }

    def skipped(self) -> list[tuple[float, str]]:
        """(t_s, reason) of windows skipped or whose circuits failed."""
        out = []
        for t_s, e, reason in self.windows:
            if e is None:
                out.append((t_s, reason or "skipped"))
            elif e.get("flags"):
                out.append((t_s, "; ".join(str(f) for f in e["flags"])))
        return out

    def summary(self) -> dict[str, Any]:
        """Counts of windows by outcome and of qualities per parameter."""
        estimated = sum(1 for _, e, _ in self.windows if e is not None)
        reasons = Counter(r.split(":")[0] for _, e, r in self.windows if e is None)
        qualities = {
            label: dict(Counter(self.series(c, p)["quality"].tolist()))
            for c, p, label, _ in PARAMETERS
        }
        return {"windows": len(self.windows), "estimated": estimated,
                "skipped": dict(reasons), "quality": qualities}  # fmt: skip


def _scale(values: np.ndarray) -> tuple[float, str]:
    """The SI prefix that puts the median magnitude of ``values`` in [1, 1000)."""
    from observer.commands.display import prefix_scale

    finite = np.abs(values[np.isfinite(values)])
    finite = finite[finite > 0]
    return prefix_scale(float(np.median(finite))) if finite.size else (1.0, "")


def _figure(trend: Trend, title: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    present = [row for row in PARAMETERS if trend.series(row[0], row[1])["t"].size]
    names = {"ia": "armature current", "if": "field current", "omega": "speed"}
    units = {"ia": "A", "if": "A", "omega": "rad/s"}
    signal_rows = [c for c in ("ia", "if", "omega") if c in trend.blocks]
    n_rows = max(1, len(present) + len(signal_rows))
    fig, axes = plt.subplots(n_rows, 1, figsize=(11, 1.9 * n_rows + 0.6), sharex=True)
    axes = np.atleast_1d(axes)
    skipped = trend.skipped()
    for ax, (circuit, p, label, unit) in zip(axes, present, strict=False):
        s = trend.series(circuit, p)
        factor, prefix = _scale(s["raw"])
        raw, std, value = s["raw"] / factor, s["std"] / factor, s["value"] / factor
        band = np.isfinite(std) & np.isfinite(raw)
        low, high = np.where(band, raw - std, np.nan), np.where(band, raw + std, np.nan)
        ax.fill_between(s["t"], low, high, color="tab:blue", alpha=0.18, lw=0,
                        label="estimate +-1 sigma")  # fmt: skip
        ax.plot(s["t"], value, color="k", lw=1.0, label="reported")
        # The band of a window that does not identify a parameter can span decades:
        # keep the axis on the identified values, and show the others at its edges.
        good = np.isfinite(raw) & (s["quality"] == "ok")
        ref = raw[good] if good.any() else raw[np.isfinite(raw)]
        shown = raw
        if ref.size:
            lo, hi = float(np.min(ref)), float(np.max(ref))
            pad = max(0.1 * (hi - lo), 0.02 * max(abs(lo), abs(hi)), 1e-12)
            ax.set_ylim(lo - pad, hi + pad)
            shown = np.clip(raw, lo - 0.9 * pad, hi + 0.9 * pad)
        for q in sorted(set(s["quality"].tolist())):
            colour, marker = QUALITY_STYLE.get(q, QUALITY_STYLE["other"])
            sel = s["quality"] == q
            ax.plot(s["t"][sel], shown[sel], ls="none", marker=marker, ms=3, color=colour,
                    label=f"window: {q}")  # fmt: skip
        ax.set_ylabel(f"{label} ({prefix}{unit})")
        ax.legend(loc="upper right", fontsize=7, ncol=5)
    for j, (ax, c) in enumerate(zip(axes[len(present) :], signal_rows, strict=False)):
        env = np.array(trend.blocks[c])
        ax.fill_between(env[:, 0], env[:, 1], env[:, 2], color=f"C{j}", alpha=0.6, lw=0.5,
                        label=f"{c}: min-max per block")  # fmt: skip
        ax.set_ylabel(f"{names[c]} ({units[c]})")
        ax.legend(loc="upper right", fontsize=7)
    for ax in axes:
        for t_s, _ in skipped:
            ax.axvline(t_s, color="tab:red", alpha=0.25, lw=1.0)
    if skipped:
        axes[0].plot([], [], color="tab:red", alpha=0.5, label="window skipped or failed")
        axes[0].legend(loc="upper right", fontsize=7, ncol=5)
    axes[-1].set_xlabel("time since the first sample (s)")
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.98))
    return fig


def render_png(trend: Trend, *, title: str) -> bytes:
    """The trend figure as PNG bytes."""
    import matplotlib.pyplot as plt

    fig = _figure(trend, title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _last_reported(trend: Trend, circuit: str, p: str) -> tuple[float | None, str, float | None]:
    """The last window's reported value, its quality and std."""
    s = trend.series(circuit, p)
    if not s["t"].size:
        return None, "-", None
    v = float(s["value"][-1])
    std = float(s["std"][-1])
    return (v if math.isfinite(v) else None), str(s["quality"][-1]), (
        std if math.isfinite(std) else None
    )  # fmt: skip


def render_html(trend: Trend, *, title: str, source: str) -> str:
    """The trend report: one self-contained page (inline PNG, no external resources)."""
    import base64

    from observer.commands.display import K_EXPLAINED, eng_pair
    from observer.diagnosis.report import html_img, html_table

    summary = trend.summary()
    png = base64.b64encode(render_png(trend, title=title)).decode("ascii")
    rows = []
    for circuit, p, label, unit in PARAMETERS:
        v, q, std = _last_reported(trend, circuit, p)
        if q == "-":
            continue
        value, sigma = eng_pair(v, std, unit)
        counts = ", ".join(f"{k} {n}" for k, n in sorted(summary["quality"][label].items()))
        rows.append([label, value, sigma, q, counts])
    skipped = ", ".join(f"{k} {n}" for k, n in sorted(summary["skipped"].items())) or "none"
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1150px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #aaa;"
        "padding:2px 6px;font-size:13px}img{max-width:100%}figure{margin:1em 0}</style>"
        "</head><body>",
        f"<h1 id='title'>{html.escape(title)}</h1>",
        f"<p id='summary'>{html.escape(source)}: {summary['windows']} windows, "
        f"{summary['estimated']} estimated, skipped: {html.escape(skipped)}.</p>",
        "<h2>Last reported values</h2>",
        html_table(rows, ["parameter", "value", "+-1 sigma", "quality", "windows by quality"]),
        f"<p>{html.escape(K_EXPLAINED.format(at=''))}.</p>",
        "<p>Quality: <b>ok</b> identified by its window; <b>held</b> not identified, the last "
        "accepted value is reported; <b>none</b> not identified and nothing to hold; others "
        "(unconfirmed, outlier, change) as the observer names them. Red lines: windows "
        "skipped (gap, stuck sensor, ...) or whose circuit failed.</p>",
        "<h2>Trend</h2>",
        html_img(
            png,
            "parameters over time with their one-sigma band and quality; currents and speed below",
        ),  # fmt: skip
        "</body></html>",
    ]
    return "\n".join(parts)
