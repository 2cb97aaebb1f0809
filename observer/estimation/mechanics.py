"""The measured speed through the shaft's own equation: sensor noise out of the EMF's regressor.

The armature's model takes the EMF as ``K * if * omega`` with ``omega`` the
*measured* speed. Its noise is not a harmless errors-in-variables term: the
drive's speed loop reacts to it. A tachometer's noise moves the current
reference, the current loop moves ``va`` and the current follows, so in a
window where the drive holds its speed the only variation of ``va`` and ``ia``
is the drive's answer to that noise, and the regressor's noise is correlated
with it. Output error then reads the noise as physics: on a P-12 held at 61
rad/s (10 kHz, 0.2 % sensor noise, the speed loop closed on the noisy
tachometer) the window fits were ``Ra`` +35 %, ``La`` +11 % and ``K`` -6.5 %
at |error / std| 5-8, and the tracker confirmed a false ``La rose 11 %``.

The speed, though, is a mechanical state: ``J domega/dt = K if ia - T_load``.
Within a window it is a smooth function of time (the load and friction,
which change on the mechanism's time scale) plus ``K/J`` times the integral
of the torque current ``if * ia`` (which carries every kink a current step
puts into the speed). :func:`smooth_speed` fits exactly that to the measured
speed by least squares -- a piecewise-linear function of time on knots
:data:`KNOT_SPACINGS_S` apart and the torque integral -- and uses the fit in
place of the samples where it leaves nothing but white noise behind; it
tries finer knots where it does not (a load that changes faster, a
compliant shaft's oscillation) and keeps the measured speed where none
fits. Tens of parameters against thousands of samples: the noise is gone,
and with it the correlation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

#: Knot spacings (s) tried, coarsest first: a rope shovel's load changes over tenths of a
#: second; finer knots follow a faster load or a shaft's torsional oscillation.
KNOT_SPACINGS_S = (0.05, 0.02, 0.01, 0.005)

#: Residuals are judged in blocks of this length (s): their means show a misfit of the
#: speed's shape, which the noise averages out of.
BLOCK_S = 1e-3

#: A fit is kept when the residual's block means scatter no more than the noise's do, within
#: this many standard errors of the ratio of the two variance estimates (``sqrt(6 / blocks)``:
#: the residual's own ``2 / blocks`` and the second differences' ``3.9 / blocks``).
MISFIT_SIGMAS = 3.0

#: Fewer samples than this: the speed is kept as measured.
MIN_SAMPLES = 64


@dataclass(frozen=True)
class SpeedFit:
    """The speed the estimator uses, and how it was made.

    Attributes
    ----------
    omega : (n,) array
        The fitted speed, or the measured one where no fit describes it.
    knot_s : float or None
        Knot spacing of the fit used (``None``: the measured speed).
    misfit : float
        The residual's block-mean scatter over the noise's (about 1 when the fit
        leaves only noise; of the last fit tried when none was kept).
    """

    omega: np.ndarray
    knot_s: float | None
    misfit: float


@njit(cache=True, nogil=True)
def _hat_normal_equations(
    pos: np.ndarray, torque: np.ndarray, omega: np.ndarray, m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Normal equations of ``omega ~ sum_j c_j hat_j(pos) + d * torque`` over hats on the
    integer knots ``0 .. m-1`` (``pos`` in knot units): the hats' tridiagonal block
    (diagonal, super-diagonal), their products with ``torque`` and ``omega``, and the
    torque column's own products."""
    diag = np.zeros(m)
    upper = np.zeros(m)
    bt = np.zeros(m)
    bo = np.zeros(m)
    tt = 0.0
    to = 0.0
    for k in range(pos.shape[0]):
        j = min(int(pos[k]), m - 2)
        w = pos[k] - j
        a = 1.0 - w
        diag[j] += a * a
        diag[j + 1] += w * w
        upper[j] += a * w
        bt[j] += a * torque[k]
        bt[j + 1] += w * torque[k]
        bo[j] += a * omega[k]
        bo[j + 1] += w * omega[k]
        tt += torque[k] * torque[k]
        to += torque[k] * omega[k]
    return diag, upper, bt, bo, tt, to


@njit(cache=True, nogil=True)
def _tridiagonal_solve(diag: np.ndarray, upper: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve a symmetric tridiagonal system (Thomas' algorithm; the hats' Gram matrix is
    diagonally dominant, so no pivoting is needed)."""
    m = diag.shape[0]
    c = np.empty(m)
    d = np.empty(m)
    c[0] = upper[0] / diag[0]
    d[0] = rhs[0] / diag[0]
    for j in range(1, m):
        den = diag[j] - upper[j - 1] * c[j - 1]
        c[j] = upper[j] / den if j < m - 1 else 0.0
        d[j] = (rhs[j] - upper[j - 1] * d[j - 1]) / den
    x = np.empty(m)
    x[m - 1] = d[m - 1]
    for j in range(m - 2, -1, -1):
        x[j] = d[j] - c[j] * x[j + 1]
    return x


def _block_means(x: np.ndarray, b: int) -> np.ndarray:
    n = x.shape[0] // b * b
    return x[:n].reshape(-1, b).mean(axis=1)


def smooth_speed(omega: np.ndarray, i_f: np.ndarray, ia: np.ndarray, dt: float) -> SpeedFit:
    """The measured speed ``omega`` (rad/s) as the shaft's equation explains it, where it does.

    See the module's description. The noise's yardstick is the scatter of the
    second differences of the measured speed's block means (blocks of
    :data:`BLOCK_S`): a smooth speed's are far below its noise's, and block
    means of a filtered (coloured) noise are as white as those of a white one.
    """
    omega = np.asarray(omega, dtype=np.float64)
    n = omega.shape[0]
    b = max(1, int(round(BLOCK_S / dt)))
    if n < MIN_SAMPLES or n // b < 16 or not np.all(np.isfinite(omega)):
        return SpeedFit(omega, None, math.nan)
    noise = float(np.var(np.diff(_block_means(omega, b), 2))) / 6.0
    if not noise > 0.0:
        return SpeedFit(omega, None, math.nan)
    torque = np.cumsum(np.asarray(i_f, dtype=np.float64) * np.asarray(ia, dtype=np.float64)) * dt
    torque -= torque.mean()
    t = np.arange(n, dtype=np.float64) * dt
    duration = t[-1]
    limit = 1.0 + MISFIT_SIGMAS * math.sqrt(6.0 / (n // b))
    misfit = math.nan
    for spacing in KNOT_SPACINGS_S:
        m = max(2, int(math.ceil(duration / spacing)) + 1)
        if 2 * m >= n // b:
            break  # knots as dense as the blocks: nothing left to judge the fit by
        pos = t * ((m - 1) / duration)
        diag, upper, bt, bo, tt, to = _hat_normal_equations(pos, torque, omega, m)
        # The torque column borders the hats' tridiagonal block: a Schur complement.
        u = _tridiagonal_solve(diag, upper, bo)
        v = _tridiagonal_solve(diag, upper, bt)
        schur = tt - float(bt @ v)
        d = (to - float(bt @ u)) / schur if schur > 1e-12 * max(tt, 1e-300) else 0.0
        c = u - v * d
        j = np.minimum(pos.astype(np.int64), m - 2)
        w = pos - j
        fit = c[j] * (1.0 - w) + c[j + 1] * w + d * torque
        r = _block_means(omega - fit, b)
        misfit = float(np.mean(r * r)) / noise
        if misfit <= limit:
            return SpeedFit(fit, spacing, misfit)
    return SpeedFit(omega, None, misfit)
