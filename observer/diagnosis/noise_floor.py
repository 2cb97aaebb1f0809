"""What a correct model's residual looks like: white current noise plus input noise through it."""

from __future__ import annotations

import math

import numpy as np

from observer.diagnosis.results import NoiseFloor


def _autocov(r: np.ndarray, max_lag: int) -> np.ndarray:
    r = r - r.mean()
    n = r.size
    return np.array([r[: n - lag] @ r[lag:] / n for lag in range(max_lag + 1)])


def _white_variance_between_lines(v: np.ndarray) -> float:
    """Variance of the white noise on ``v`` where its spectrum is a chopper's line alone near
    Nyquist (the floor of its spectrum between lines); infinite otherwise."""
    from observer.diagnosis.chain import voltage_spectrum

    x = np.asarray(v, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size < 256:
        return math.inf
    spectrum = voltage_spectrum(x, 1.0)
    return spectrum.noise_v**2 if spectrum.line else math.inf


#: The finest resolution a recorded current is credited with: a 16-bit converter's
#: quantisation over twice the current's largest magnitude. No drive's front end resolves
#: finer, and a noise-free recording (the ideal drive at ``--noise 0``) left a floor of zero:
#: ``diagnose`` stopped on a division by it, and any model's rounding would have been
#: structure.
FINEST_BITS = 16


def resolution_variance(current: np.ndarray) -> float:
    """Variance (A^2) of :data:`FINEST_BITS` quantisation over ``±max|current|``."""
    x = np.asarray(current, dtype=np.float64)
    x = x[np.isfinite(x)]
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    step = 2.0 * peak / 2.0**FINEST_BITS
    return step * step / 12.0


def noise_floor(
    circuit: str,
    residual: np.ndarray,
    pole: float,
    gain: float,
    input_voltage: np.ndarray,
    resolution_var: float = 0.0,
) -> NoiseFloor:
    """Estimate the residual a correct model would leave, for one circuit.

    A correct output-error model leaves ``e = n_i - G*n_v``: white current noise
    ``n_i`` plus white input-voltage noise through the winding's response
    ``G = gain/(1 - pole*z^-1)``, an AR(1) with autocovariance
    ``s*pole^lag``. Slow structure from a missing effect adds an almost
    constant autocovariance over short lags. For a fast winding (time constant
    under 60 samples) the autocovariance at lags 1..3 tau is fitted by
    ``c + s*pole^lag``; ``c`` is structure, ``s`` the coloured floor. For a slow
    winding the two are not separable over short lags, so the input noise is
    measured on the input itself: the voltage is held piecewise constant by the
    drive, so the robust spread of its first differences is its noise. A
    chopper's voltage seen through a filter is not: its pulses' ripple moves every
    difference, and the spread measured the ripple (the P-12 behind a chopper at
    10 kHz and an RC voltage filter: a floor of 1.4 A rms against a residual of
    0.07-0.12 A, under which a 1 V brush drop went unseen). Where the voltage's
    spectrum shows such a line alone near Nyquist
    (:attr:`~observer.diagnosis.chain.VoltageSpectrum.line`), the noise is the
    floor of its spectrum between the lines, if smaller. (A bridge's ripple
    through the filter widens the spread too, by less; kept there: taken off, a
    healthy motor's field residual, periodic at 1x shaft speed at 0.3-0.8 mA, came
    back ``unexplained`` in 8 of 144 converter-fed diagnoses.)
    The white part is at least ``resolution_var`` (:func:`resolution_variance`).
    """
    r = residual[np.isfinite(residual)]
    total = float(np.var(r))
    tau = -1.0 / math.log(pole) if 0 < pole < 1 else math.inf
    if tau < 60:
        m = int(min(max(6, 3 * tau), r.size // 4))
        acov = _autocov(r, m)
        lags = np.arange(1, m + 1)
        design = np.column_stack([np.ones(m), pole**lags])
        (c_slow, s), *_ = np.linalg.lstsq(design, acov[1:], rcond=None)
        s = max(float(s), 0.0)
        c_slow = max(float(c_slow), 0.0)
        white = max(float(acov[0]) - s - c_slow, 1e-3 * total)
    else:
        dv = np.diff(input_voltage)
        mad = float(np.median(np.abs(dv - np.median(dv))))
        var_v = min((mad / 0.6745) ** 2 / 2.0, _white_variance_between_lines(input_voltage))
        s = var_v * gain * gain / (1.0 - pole * pole) if pole < 1 else 0.0
        acov = _autocov(r, 1)
        white = max(float(acov[0] - acov[1]) - s * (1 - pole), 0.05 * total)
    white = max(white, resolution_var)
    floor = white + s
    if not floor > 0.0:  # a current that never left zero: nothing to scale by
        floor = white = math.ulp(1.0)
    tau_ar = (1 + pole) / (1 - pole) if pole < 1 else float(r.size)
    tau_int = (white + s * tau_ar) / floor
    return NoiseFloor(circuit, floor, white, s, pole, tau_int, total)
