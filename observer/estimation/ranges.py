"""What a window must be to be estimated, and where the swarm searches.

The checks every estimator runs on its signals (:func:`check_signals`), the
one array type the kernels are compiled for (:func:`kernel_array`), and the
swarm's search box, :class:`SearchRange`, derived from the data alone
(:func:`field_search_range`, :func:`armature_search_range`) when not configured.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


class EstimationError(ValueError):
    """The data cannot support an estimate (e.g. a winding without current)."""


@dataclass(frozen=True)
class SearchRange:
    """Bounds of the swarm search in physical units.

    Attributes
    ----------
    resistance_ohm, inductance_h : (low, high)
    """

    resistance_ohm: tuple[float, float]
    inductance_h: tuple[float, float]

    def __post_init__(self) -> None:
        for name in ("resistance_ohm", "inductance_h"):
            lo, hi = getattr(self, name)
            if not (0 < lo < hi and math.isfinite(hi)):
                raise ValueError(f"search range {name} needs 0 < low < high, got ({lo}, {hi})")

    def log_bounds(self) -> np.ndarray:
        """The swarm's box: ``[[log10 R_lo, log10 R_hi], [log10 L_lo, log10 L_hi]]``."""
        return np.log10(np.array([self.resistance_ohm, self.inductance_h], dtype=np.float64))

    def around(self, resistance_ohm: float, inductance_h: float, factor: float) -> SearchRange:
        """A range ``[x/factor, x*factor]`` around a point, clipped to this range."""
        if factor <= 1:
            raise ValueError(f"factor must be > 1, got {factor}")

        def clip(x: float, lim: tuple[float, float]) -> tuple[float, float]:
            lo = min(max(x / factor, lim[0]), lim[1] / factor)
            hi = max(min(x * factor, lim[1]), lim[0] * factor)
            return lo, hi

        return SearchRange(
            clip(resistance_ohm, self.resistance_ohm), clip(inductance_h, self.inductance_h)
        )


def kernel_array(x: Any) -> np.ndarray:
    """Contiguous, writable float64: the one array type the kernels are compiled for.

    numba compiles a separate specialisation for read-only arrays (a Recording's
    are), which on a cold cache costs seconds at the first real window.
    """
    return np.require(x, dtype=np.float64, requirements=["C", "W"])


def check_signals(**signals: np.ndarray) -> int:
    n = -1
    for name, x in signals.items():
        if x.ndim != 1:
            raise EstimationError(f"{name} must be one-dimensional, got shape {x.shape}")
        if n >= 0 and x.shape[0] != n:
            raise EstimationError(
                f"signals differ in length: {name} has {x.shape[0]}, expected {n}"
            )
        n = x.shape[0]
        if not np.all(np.isfinite(x)):
            raise EstimationError(f"{name} contains NaN or Inf")
    if n < 10:
        raise EstimationError(f"need at least 10 samples, got {n}")
    return n


#: A field voltage whose mean is below this share of its rms, while the field current flows,
#: reads no voltage at all (rather than one of the wrong sign).
ZERO_MEAN_SHARE = 0.05


def field_search_range(vf: np.ndarray, i_f: np.ndarray, dt: float) -> SearchRange:
    """A wide search range for ``(Rf, Lf)`` derived from the data alone.

    The resistance is centred on the static least-squares ratio ``vf/if`` and
    spans a factor 4 either way; the time constant spans from a tenth of a
    sample period to twice the record length.
    """
    n = check_signals(vf=vf, i_f=i_f)
    power = float(np.dot(i_f, i_f))
    if power <= 0 or np.sqrt(power / n) < 1e-9:
        raise EstimationError("the field current is zero: the field circuit is not excited")
    r0 = float(np.dot(vf, i_f)) / power
    if not r0 > 0:
        mean_v = float(np.mean(vf))
        rms_v = float(np.sqrt(np.mean(vf * vf)))
        if abs(mean_v) < ZERO_MEAN_SHARE * rms_v:
            # Not a sign: no voltage at all on average while the current flows (a field
            # chopper sampled bare at its carrier frequency reads its freewheeling phase
            # every time).
            raise EstimationError(
                f"the field voltage reads about zero on average ({mean_v:.3g} V, rms "
                f"{rms_v:.3g} V) while the field current is {float(np.mean(i_f)):.3g} A: the "
                "channel does not read the winding's voltage (a converter's pulses sampled in "
                "step with the ADC and no anti-aliasing filter, or the channel not connected); "
                "check the vf channel and its front end ([chain])"
            )
        raise EstimationError(
            f"field voltage and current do not correlate positively (vf/if = {r0:.3g} ohm): "
            "check the sign and scaling of the field channels"
        )
    return _range_from(r0, 4.0, dt, n)


def armature_search_range(
    va: np.ndarray, ia: np.ndarray, i_f: np.ndarray, omega: np.ndarray, dt: float
) -> SearchRange:
    """A wide search range for ``(Ra, La)`` derived from the data alone.

    Static least squares of ``va = Ra*ia + K*(if*omega)`` centres the
    resistance when it is well determined; otherwise the centre is a tenth of
    ``rms(va)/rms(ia)`` (typical of a loaded machine). It spans a factor 10
    either way; the time constant spans as for the field.
    """
    n = check_signals(va=va, ia=ia, i_f=i_f, omega=omega)
    ia_rms = float(np.sqrt(np.mean(ia * ia)))
    if ia_rms < 1e-9:
        raise EstimationError("the armature current is zero: the armature circuit is not excited")
    va_rms = float(np.sqrt(np.mean(va * va)))
    center = 0.1 * va_rms / ia_rms
    design = np.column_stack([ia, i_f * omega])
    coef, _, rank, _ = np.linalg.lstsq(design, va, rcond=None)
    if rank == 2:
        resid = va - design @ coef
        s2 = float(resid @ resid) / max(n - 2, 1)
        cov = s2 * np.linalg.inv(design.T @ design)
        if coef[0] > 0 and math.sqrt(cov[0, 0]) < 0.3 * coef[0]:
            center = float(coef[0])
    if not center > 0:
        raise EstimationError("the armature voltage is zero: the armature circuit is not excited")
    return _range_from(center, 10.0, dt, n)


def _range_from(r_center: float, factor: float, dt: float, n: int) -> SearchRange:
    r_lo, r_hi = r_center / factor, r_center * factor
    tau_lo, tau_hi = 0.1 * dt, 2.0 * n * dt
    return SearchRange((r_lo, r_hi), (r_lo * tau_lo, r_hi * tau_hi))
