"""Where the residual exceeds the noise floor: time windows, operating conditions, shaft angle.

Bin means of the residual against an operating condition (field current,
``|ia|``, sign of ``ia``, speed, time, current slopes) are judged against the
floor's variance for that many *correlated* samples; time windows by their
mean square; a component periodic in shaft angle by its harmonic amplitude.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from observer.diagnosis.results import CURRENT_CHANNEL, ConditionStructure, Mismatch, NoiseFloor

#: A located structure: a condition's bin means, or a window, this many sigma above the floor.
STRUCTURE_Z = 6.0


def _leave_centre_out_mean(x: np.ndarray, half_width: int = 5) -> np.ndarray:
    """Mean of ``x`` over ``k-w .. k+w`` without sample ``k`` itself."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    n = x.size
    k = np.arange(n)
    lo = np.maximum(k - half_width, 0)
    hi = np.minimum(k + half_width + 1, n)
    return (c[hi] - c[lo] - x) / np.maximum(hi - lo - 1, 1)


def conditions(rec: Any, armature_tau_s: float) -> dict[str, tuple[np.ndarray, str]]:
    """Operating conditions to bin residuals against: ``{name: (values, words)}``.

    Currents and speed are local means of the measurements *without the sample
    itself*, over windows long against the armature time constant: a residual
    binned against the noisy signal it was computed from would find that
    signal's noise (a narrow band of a noisy value selects its noise), and the
    residual remembers the noise of the last few time constants (through the
    model's response, and through the drive's current loop). Armature-current
    conditions use +-5 time constants, field current and speed +-25.
    """
    dt = rec.dt
    t = np.asarray(rec.t) - rec.t[0]
    fast = max(5, int(round(5 * armature_tau_s / dt)))
    slow = max(5 * fast, int(round(0.1 / dt)))
    i_f = _leave_centre_out_mean(np.asarray(rec["if"]), slow)
    ia = _leave_centre_out_mean(np.asarray(rec["ia"]), fast)
    omega = _leave_centre_out_mean(np.asarray(rec["omega"]), slow)
    return {
        "if": (i_f, "field current"),
        "|ia|": (np.abs(ia), "armature current magnitude"),
        "sign(ia)": (np.sign(ia), "armature current direction"),
        "omega": (omega, "speed"),
        "time": (t, "time (accumulated I^2R losses)"),
        "|dia/dt|": (np.abs(np.gradient(ia, dt)), "armature current slope (fast transients)"),
        "|dif/dt|": (np.abs(np.gradient(i_f, dt)), "field current slope (field transients)"),
    }


def binned_structure(
    residual: np.ndarray, x: np.ndarray, floor: NoiseFloor, n_bins: int = 8
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """z-score of the residual's bin means against ``x`` under the floor.

    Returns ``(z, centers, means, sigmas)``; ``z = (chi2 - J)/sqrt(2J)`` with
    each bin mean's variance ``floor * tau_eff / m`` for ``m`` correlated samples.
    """
    ok = np.isfinite(residual)
    r, x = residual[ok], x[ok]
    if np.unique(x).size <= 3:
        edges = np.unique(x)
        idx = np.searchsorted(edges, x)
    else:
        edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1)[1:-1]))
        idx = np.searchsorted(edges, x, side="right")
    n_b = int(idx.max()) + 1
    counts = np.bincount(idx, minlength=n_b).astype(float)
    sums = np.bincount(idx, weights=r, minlength=n_b)
    use = counts > 10
    means = sums[use] / counts[use]
    centers = (np.bincount(idx, weights=x, minlength=n_b)[use]) / counts[use]
    # A bin's samples are not all contiguous: their correlation time is at most tau_int.
    sigma = np.sqrt(floor.variance_a2 * np.minimum(floor.tau_int, counts[use]) / counts[use])
    j = means.size
    if j < 2:
        return 0.0, centers, means, sigma
    # The grand mean is free (i0, K absorb it): compare bins with their weighted mean.
    w = 1 / sigma**2
    mu = float(np.sum(w * means) / np.sum(w))
    chi2 = float(np.sum(((means - mu) / sigma) ** 2))
    z = (chi2 - (j - 1)) / math.sqrt(2 * (j - 1))
    return z, centers, means, sigma


def locate(
    rec: Any,
    residuals: dict[str, np.ndarray],
    floors: dict[str, NoiseFloor],
    conds: dict[str, tuple[np.ndarray, str]],
) -> tuple[tuple[Mismatch, ...], tuple[ConditionStructure, ...]]:
    """Time windows and operating conditions where the residual exceeds the floor."""
    t = np.asarray(rec.t) - rec.t[0]
    structures: list[ConditionStructure] = []
    mismatches: list[Mismatch] = []
    for circuit, r in residuals.items():
        fl = floors[circuit]
        ch = CURRENT_CHANNEL[circuit]
        for name, (x, words) in conds.items():
            if circuit == "field" and name in ("|ia|", "sign(ia)", "|dia/dt|", "omega"):
                continue
            z, centers, means, sigma = binned_structure(r, x, fl)
            if z > STRUCTURE_Z:
                hi = centers[int(np.argmax(np.abs(means) / sigma))]
                desc = (
                    f"{ch} residual depends on {words} (z = {z:.0f}); largest at {name} = {hi:.3g}"
                )
                w_ = 1 / sigma**2
                offset = np.abs(means - np.sum(w_ * means) / np.sum(w_))
                size = float(offset.max()) / math.sqrt(fl.variance_a2)
                structures.append(
                    ConditionStructure(
                        ch, name, z, tuple(centers), tuple(means), tuple(sigma), desc, size
                    )
                )
        # Time windows: mean square against the floor's.
        w = max(50, int(round(0.25 / rec.dt)))
        n_w = r.size // w
        if n_w < 1:
            continue
        blocks = r[: n_w * w].reshape(n_w, w)
        # A block wholly outside the segments (NaN) has no mean square and is not flagged.
        counts = np.sum(np.isfinite(blocks), axis=1)
        ms = np.where(counts > 0, np.nansum(blocks**2, axis=1) / np.maximum(counts, 1), np.nan)
        sd = fl.variance_a2 * math.sqrt(2 * min(fl.tau_int, w) / w)
        zw = (ms - fl.variance_a2) / sd
        flagged = zw > STRUCTURE_Z
        k = 0
        while k < n_w:
            if not flagged[k]:
                k += 1
                continue
            k1 = k
            while k1 + 1 < n_w and flagged[k1 + 1]:
                k1 += 1
            i0, i1 = k * w, (k1 + 1) * w
            mismatches.append(
                Mismatch(
                    float(t[i0]),
                    float(t[min(i1, t.size - 1)]),
                    ch,
                    _describe_window(conds, i0, i1, circuit),
                    float(zw[k : k1 + 1].max()),
                )  # fmt: skip
            )
            k = k1 + 1
    structures.sort(key=lambda s: -s.z)
    mismatches.sort(key=lambda m: -m.z)
    return tuple(mismatches[:20]), tuple(structures)


def _describe_window(
    conds: dict[str, tuple[np.ndarray, str]], i0: int, i1: int, circuit: str
) -> str:
    words = []
    for name, (x, text) in conds.items():
        if name == "time" or (circuit == "field" and name in ("|ia|", "sign(ia)", "|dia/dt|")):
            continue
        seg = x[i0:i1]
        if name == "sign(ia)":
            if np.any(np.diff(np.sign(seg)) != 0):
                words.append("armature current reversals")
            continue
        ref = np.median(np.abs(x)) + 1e-12
        level = np.median(np.abs(seg)) / ref
        if level > 1.3:
            words.append(f"high {text} ({level:.1f}x median)")
        elif level < 0.5 and name in ("if", "omega"):
            words.append(f"low {text} ({level:.1f}x median)")
    return ", ".join(words) if words else "no distinctive operating condition"


def periodic_structure(
    rec: Any, residual: np.ndarray, floor: NoiseFloor, channel: str
) -> ConditionStructure | None:
    """A component of the residual periodic in shaft angle (harmonics 1..12), if significant."""
    ok = np.isfinite(residual)
    angle = np.cumsum(rec["omega"]) * rec.dt
    best: tuple[float, int, float] | None = None
    n_eff = ok.sum() / max(floor.tau_int, 1.0)
    # Each coefficient's standard error under the floor, with correlated samples.
    se = math.sqrt(2 * floor.variance_a2 / n_eff)
    for h in range(1, 13):
        design = np.column_stack([np.cos(h * angle[ok]), np.sin(h * angle[ok])])
        coef, *_ = np.linalg.lstsq(design, residual[ok], rcond=None)
        amp = float(np.hypot(*coef))
        z = amp / se
        if z > 8 and (best is None or z > best[0]):
            best = (z, h, amp)
    if best is None:
        return None
    z, h, amp = best
    desc = (
        f"{channel} residual periodic at {h}x shaft speed (amplitude {amp:.3g} A, z = {z:.0f}): "
        "e.g. commutation ripple, an eccentric rotor or a speed-sensor error"
    )
    return ConditionStructure(
        channel, f"angle x{h}", z, (), (), (), desc, amp / math.sqrt(floor.variance_a2)
    )
