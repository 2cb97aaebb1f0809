"""One self-contained HTML page of a diagnosis: tables and inline PNG plots.

Plots (matplotlib, Agg backend, embedded as base64 so the page needs nothing
else): measured vs simulated current before and after the extension, the
residual over time with the located segments marked, the residual against the
operating condition that exposes the mismatch, and the fitted extension itself
(e.g. the saturation curve).
"""

from __future__ import annotations

import base64
import html
import io
import math
from typing import Any

import numpy as np

from observer.diagnosis import kernels as dk
from observer.diagnosis.locate import binned_structure
from observer.diagnosis.results import CURRENT_CHANNEL, Diagnosis, Finding


def figure_png(fig: Any) -> str:
    """A matplotlib figure as base64 PNG (the figure is closed)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def html_img(data: str, alt: str) -> str:
    """An inline ``<figure>`` of a base64 PNG with its caption."""
    text = html.escape(alt)
    return (
        f'<figure><img alt="{text}" src="data:image/png;base64,{data}">'
        f"<figcaption>{text}</figcaption></figure>"
    )


def _focus_circuit(diag: Diagnosis) -> str:
    best = diag.findings[0] if diag.findings else None
    if best is not None:
        return "field" if best.channel == "if" else "armature"
    return max(diag.floors, key=lambda c: diag.floors[c].excess_ratio)


def _window(diag: Diagnosis, rec: Any, circuit: str) -> slice:
    n = rec.n_samples
    width = min(n, max(int(2.0 / rec.dt), 200))
    ch = CURRENT_CHANNEL[circuit]
    seg = next((m for m in diag.mismatch if m.channel == ch), None)
    if seg is None:
        r0 = diag.residuals_before[circuit]
        r1 = diag.residuals_after.get(circuit, r0)
        # Where the extension changes the residual most.
        change = np.convolve(np.abs(r0 - r1), np.ones(width), mode="valid")
        start = int(np.argmax(change)) if change.size else 0
    else:
        start = int(seg.t0 / rec.dt)
    start = max(0, min(start, n - width))
    return slice(start, start + width)


def _plot_measured(diag: Diagnosis, rec: Any, circuit: str) -> str:
    import matplotlib.pyplot as plt

    ch = CURRENT_CHANNEL[circuit]
    sl = _window(diag, rec, circuit)
    t = rec.t[sl] - rec.t[0]
    meas = rec[ch][sl]
    before = meas - diag.residuals_before[circuit][sl]
    fig, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    axes[0].plot(t, meas, lw=0.6, color="0.5", label="measured")
    axes[0].plot(t, before, lw=1.0, color="C3", label="plain model")
    if circuit in diag.residuals_after:
        after = meas - diag.residuals_after[circuit][sl]
        top = diag.findings[0]
        name = top.effect if top.accepted else f"{top.effect} (rejected)"
        axes[0].plot(t, after, lw=1.0, color="C0", ls="--", label=f"with {name}")
        axes[1].plot(t, diag.residuals_after[circuit][sl], lw=0.6, color="C0", label=f"with {name}")
    axes[1].plot(t, diag.residuals_before[circuit][sl], lw=0.6, color="C3", label="plain model")
    axes[0].set_ylabel(f"{ch} (A)")
    axes[1].set_ylabel("residual (A)")
    axes[1].set_xlabel("time (s)")
    axes[0].legend(loc="best", fontsize=8)
    axes[1].legend(loc="best", fontsize=8)
    axes[0].set_title(f"{ch}: measured vs simulated, before and after")
    return figure_png(fig)


def _plot_residual_time(diag: Diagnosis, rec: Any) -> str:
    import matplotlib.pyplot as plt

    t = rec.t - rec.t[0]
    fig, axes = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    for ax, circuit in zip(axes, ("field", "armature"), strict=True):
        ch = CURRENT_CHANNEL[circuit]
        r0 = diag.residuals_before[circuit]
        ax.plot(t, r0, lw=0.4, color="C3", label="plain model")
        if circuit in diag.residuals_after:
            ax.plot(t, diag.residuals_after[circuit], lw=0.4, color="C0", alpha=0.8, label="after")
        floor = math.sqrt(diag.floors[circuit].variance_a2)
        ax.axhline(3 * floor, color="k", lw=0.6, ls=":")
        ax.axhline(-3 * floor, color="k", lw=0.6, ls=":", label="3x noise floor")
        for m in diag.mismatch:
            if m.channel == ch:
                ax.axvspan(m.t0, m.t1, color="orange", alpha=0.25)
        ax.set_ylabel(f"{ch} residual (A)")
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel("time (s); shaded: located mismatch")
    axes[0].set_title("residual over time")
    return figure_png(fig)


def _plot_condition(diag: Diagnosis) -> str | None:
    import matplotlib.pyplot as plt

    binned = [s for s in diag.structure if s.condition in diag.conditions]
    if not binned:
        return None
    s = binned[0]
    circuit = "field" if s.channel == "if" else "armature"
    x, words = diag.conditions[s.condition]
    fig, ax = plt.subplots(figsize=(8, 4))
    for label, res, color in (
        ("plain model", diag.residuals_before[circuit], "C3"),
        ("after", diag.residuals_after.get(circuit), "C0"),
    ):
        if res is None:
            continue
        _, centers, means, sigma = binned_structure(res, x, diag.floors[circuit])
        ax.errorbar(centers, means, yerr=2 * sigma, fmt="o-", color=color, label=label, capsize=3)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel(f"{s.condition} ({words})")
    ax.set_ylabel(f"mean {s.channel} residual (A), +-2 sigma of the floor")
    ax.set_title(f"residual vs {words}")
    ax.legend(fontsize=8)
    return figure_png(fig)


def _plot_extension(diag: Diagnosis, rec: Any, finding: Finding) -> str | None:
    import matplotlib.pyplot as plt

    p = finding.full
    ctx = diag.context
    names = finding.effect.split("+")
    fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 3.6), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        if name == "field_saturation":
            i = np.linspace(0, 1.2 * ctx.if_peak_a, 200)
            c = p[dk.I_SAT]
            ax.plot(i, i, "k:", label="linear (plain model)")
            ax.plot(i, i / (1 + c * i), "C0", label="flux g(if) = if/(1+c|if|)")
            ax.plot(i, 1 / (1 + c * i) ** 2 * ctx.if_peak_a, "C2--", label="Lf,inc/Lf (scaled)")
            ax.set_xlabel("field current (A)")
            ax.set_ylabel("equivalent field current (A)")
        elif name == "thermal_drift":
            theta = np.empty(rec.n_samples)
            ia, i_f = rec["ia"], rec["if"]
            loss = diag.baseline_full[dk.I_RA] * ia**2 + diag.baseline_full[dk.I_RF] * i_f**2
            dk.thermal_state(p, loss, rec.dt, theta)
            ax.plot(rec.t - rec.t[0], 100 * theta, "C0")
            ax.set_xlabel("time (s)")
            ax.set_ylabel("resistance rise (%)")
        elif name == "brush_drop":
            i = np.linspace(-ctx.ia_peak_a, ctx.ia_peak_a, 400)
            ax.plot(i, p[dk.I_VB] * np.tanh(i / (0.01 * ctx.ia_peak_a)), "C0")
            ax.set_xlabel("armature current (A)")
            ax.set_ylabel("brush drop (V)")
        elif name == "armature_reaction":
            i = np.linspace(-ctx.ia_peak_a, ctx.ia_peak_a, 200)
            ax.plot(i, 100 * (1 - p[dk.I_BETA] * np.abs(i)), "C0")
            ax.set_xlabel("armature current (A)")
            ax.set_ylabel("effective flux (% of no-load)")
        elif name == "eddy_currents":
            t = np.linspace(0, 3 * ctx.field_time_constant_s, 400)
            r, ell, k2, te = p[dk.I_RF], p[dk.I_LF], p[dk.I_K2], p[dk.I_TE]
            ax.plot(t, 1 - np.exp(-t * r / ell), "k:", label="plain RL")
            step = np.zeros_like(t)
            cur = eddy = 0.0
            h = t[1] - t[0]
            p00, p01, p10, p11, g0, g1 = dk._eddy_step(r, ell, k2, te, h)
            for k in range(1, t.size):
                cur, eddy = p00 * cur + p01 * eddy + g0 * r, p10 * cur + p11 * eddy + g1 * r
                step[k] = cur
            ax.plot(t, step, "C0", label=f"with eddy path (k2={k2:.2f}, tau_e={te * 1e3:.1f} ms)")
            ax.set_xlabel("time (s)")
            ax.set_ylabel("field current step response (p.u.)")
        elif name == "sensor_offset":
            ax.bar(["ia offset (A)", "if offset (A)"], [p[dk.I_OFF_IA], p[dk.I_OFF_IF]], color="C0")
        elif name == "sampling_skew":
            ax.bar(["current delay (samples)"], [p[dk.I_SKEW] / ctx.dt], color="C0")
        ax.set_title(name)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    return figure_png(fig)


def html_table(rows: list[list[str]], header: list[str]) -> str:
    """An HTML table, every cell escaped."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _g(x: Any) -> str:
    if isinstance(x, float):
        return f"{x:.5g}"
    return str(x)


def render_html(diag: Diagnosis, rec: Any, *, title: str = "dcobserver diagnosis") -> str:
    """The report page as a string."""
    import matplotlib

    matplotlib.use("Agg")
    circuit = _focus_circuit(diag)
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #aaa;"
        "padding:2px 6px;font-size:13px}img{max-width:100%}figure{margin:1em 0}"
        ".verdict{font-size:1.4em;padding:0.4em;background:#eef}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        f"<p class='verdict' id='verdict'>Verdict: <b>{html.escape(diag.verdict)}</b></p>",
        f"<p id='description'>{html.escape(diag.description)}</p>",
        "<h2>Baseline (plain model)</h2>",
    ]
    rows = []
    for c in ("field", "armature"):
        e = diag.baseline[c]
        fl = diag.floors[c]
        rows.append(
            [c, _g(e.resistance_ohm), _g(e.inductance_h), _g(e.emf_constant_h or ""),
             _g(diag.baseline_rms[c]), _g(math.sqrt(fl.variance_a2)), f"{fl.excess_ratio:.2f}"]
        )  # fmt: skip
    parts.append(
        html_table(
            rows,
            ["circuit", "R (ohm)", "L (H)", "K (H)", "rms (A)", "noise floor (A)", "rms/floor"],
        )
    )
    parts.append("<h2>Located mismatch</h2>")
    if diag.mismatch or diag.structure:
        parts.append(
            html_table(
                [
                    [_g(m.t0), _g(m.t1), m.channel, m.conditions, f"{m.z:.0f}"]
                    for m in diag.mismatch
                ],
                ["t0 (s)", "t1 (s)", "channel", "conditions", "z"],
            )
        )
        parts.append(
            "<ul>"
            + "".join(f"<li>{html.escape(s.description)}</li>" for s in diag.structure)
            + "</ul>"
        )
    else:
        parts.append("<p>No structure above the noise floor.</p>")
    parts.append("<h2>Candidates (best first)</h2>")
    rows = []
    for f in diag.findings:
        ev = f.evidence
        rows.append(
            [f.effect, "yes" if f.accepted else "no",
             ", ".join(f"{k}={v:.4g}" for k, v in {**f.params, **f.magnitude}.items()),
             f"{_g(f.rms_before)} -> {_g(f.rms_after)} ({f.channel})",
             f"{100 * ev['holdout_gain']:.2f} %", f"{ev['holdout_lr']:.1f}", f"{ev['ic_gain']:.1f}"]
        )  # fmt: skip
    parts.append(
        html_table(
            rows,
            [
                "effect",
                "earns it",
                "parameters",
                "rms before -> after (A)",
                "held-out gain",
                "held-out LR",
                "IC gain",
            ],
        )  # fmt: skip
    )
    if diag.findings:
        best = diag.findings[0]
        parts.append(f"<p><b>{html.escape(best.effect)}</b>: {html.escape(best.explanation)}. "
                     f"Adds: <code>{html.escape(best.equation)}</code></p>")  # fmt: skip
        corr = best.corrected
        parts.append(
            html_table(
                [
                    [
                        c,
                        _g(diag.baseline[c].resistance_ohm),
                        _g(corr[c]["R"]),
                        _g(diag.baseline[c].inductance_h),
                        _g(corr[c]["L"]),
                    ]
                    for c in ("field", "armature")
                ],
                ["circuit", "R plain", "R corrected", "L plain", "L corrected"],
            )  # fmt: skip
        )
    parts.append("<h2>Plots</h2>")
    parts.append(
        html_img(_plot_measured(diag, rec, circuit), "measured vs simulated, before and after")
    )
    residual = _plot_residual_time(diag, rec)
    parts.append(html_img(residual, "residual over time with located segments"))
    cond = _plot_condition(diag)
    if cond:
        parts.append(html_img(cond, "residual vs the exposing operating condition"))
    if diag.findings:
        ext = _plot_extension(diag, rec, diag.findings[0])
        if ext:
            parts.append(html_img(ext, f"fitted extension: {diag.findings[0].effect}"))
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(diag: Diagnosis, rec: Any, path: str, *, title: str | None = None) -> None:
    """Write :func:`render_html` to ``path``."""
    from observer.recording import atomic_open

    text = render_html(diag, rec, title=title or "dcobserver diagnosis")
    with atomic_open(path, "w") as f:
        f.write(text)
