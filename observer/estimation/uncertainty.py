"""How far an estimate can be trusted: the sandwich (Newey-West) bound and input noise.

:func:`crlb_std` is the one-sigma uncertainty at a least-squares optimum, kept
honest for the coloured output-error residual; :func:`input_noise_variance`
reads the variance of noise on the measured input voltage from the residual's
autocorrelation (the errors-in-variables bias the armature estimator removes).
"""

from __future__ import annotations

import math

import numpy as np

from observer.estimation import kernels


def crlb_std(
    jac: np.ndarray, residual: np.ndarray, time_constant_samples: float = 0.0
) -> np.ndarray:
    """One-sigma uncertainty of least-squares parameters at the optimum.

    With white residuals this is the Cramer-Rao bound ``sigma^2 (J'J)^-1``. The
    output-error residual is not white, though: noise on the measured voltages
    reaches it through the model and lasts a few time constants. The sandwich
    ``(J'J)^-1 S (J'J)^-1``, with ``S`` the Bartlett-weighted (Newey-West)
    long-run covariance of the scores ``J_k r_k`` over three time constants,
    keeps the bound honest then, and equals it when the residual is white.
    """
    n, p = jac.shape
    max_lag = int(min(3.0 * time_constant_samples, 400, n // 4))
    # Bartlett-weighted long-run covariance as overlapping batch means: the
    # covariance of the scores' sums over every run of max_lag + 1 samples
    # (one pass over the samples with J'J, instead of one product per lag).
    batch = max_lag + 1 if max_lag >= 1 else 0
    jtj, sums = kernels.score_products(
        np.ascontiguousarray(jac, dtype=np.float64),
        np.ascontiguousarray(residual, dtype=np.float64),
        batch,
    )
    try:
        bread = np.linalg.inv(jtj)
    except np.linalg.LinAlgError:
        return np.full(p, np.inf)
    sigma2 = float(residual @ residual) / max(n - p, 1)
    white = sigma2 * np.diag(bread)
    if batch:
        meat = sums / batch * (n / (n + 1 - batch))
        meat *= n / max(n - p, 1)
        robust = np.diag(bread @ meat @ bread)
        # Never report less than the white-noise bound.
        white = np.maximum(white, robust)
    return np.where(white >= 0, np.sqrt(np.abs(white)), np.inf)


# ------------------------------------------------- errors-in-variables bias


def input_noise_variance(residual: np.ndarray, a: float, b: float) -> float:
    """Variance of white input-voltage noise that explains the residual's autocorrelation.

    At the true parameters the output-error residual is ``n_i - G*n_v``: white
    current noise plus input noise through the model's impulse response
    ``h_j = b*a^j``. Only the second term correlates across lags, with
    autocovariance ``s * b^2 * a^tau / (1 - a^2)``; ``s`` is fitted by least
    squares over lags 1 to three time constants, beside a constant for slow
    structure.
    """
    if not math.exp(-1.0) <= a < 1.0:
        # Time constant under one sample: input noise through the model is as
        # white as current noise, so the two cannot be told apart.
        return 0.0
    r = residual - residual.mean()
    n = r.size
    tau_samples = -1.0 / math.log(a) if 0 < a < 1 else float(n)
    m = int(min(200, max(5, 3 * tau_samples), n // 4))
    cov = kernels.autocovariances(np.ascontiguousarray(r), m)
    shape = b * b * a ** np.arange(1, m + 1) / (1.0 - a * a)
    # A constant term takes up slow structure (model error, drift) that would
    # otherwise be read as input noise and over-correct.
    design = np.column_stack([shape, np.ones(m)])
    (s, _slow), *_ = np.linalg.lstsq(design, cov, rcond=None)
    return max(float(s), 0.0)
