"""The estimators this project is compared with, written as their users would write them.

* equation-error least squares on the discrete ARX form ``i[k+1] = a*i[k] + b*v[k]``
  and on the continuous form ``v = R*i + L*di/dt`` with a numerical derivative,
  and recursive least squares: the classical methods the paper's reference
  values came from;
* output error with :func:`scipy.optimize.least_squares` and
  :func:`scipy.optimize.differential_evolution`;
* pyswarms' ``GlobalBestPSO`` with a numpy objective or with this project's
  compiled cost.

Field functions return ``(R, L)``; armature functions ``(R, L, K)``.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
from collections.abc import Callable

import numpy as np
from numba import njit

from observer.estimation import kernels

# ------------------------------------------------------- equation error (LS)


def _rl_from_arx(a: float, b: float, dt: float) -> tuple[float, float]:
    """``(R, L)`` of the exact ZOH model ``a = exp(-R dt/L)``, ``b = (1-a)/R``."""
    if not (0.0 < a < 1.0) or b == 0.0:
        return math.nan, math.nan
    resistance = (1.0 - a) / b
    return resistance, -resistance * dt / math.log(a)


def arx_ls_field(vf: np.ndarray, i_f: np.ndarray, dt: float) -> tuple[float, float]:
    """Least squares of ``if[k+1] = a*if[k] + b*vf[k]`` (equation error, discrete form)."""
    design = np.column_stack([i_f[:-1], vf[:-1]])
    (a, b), *_ = np.linalg.lstsq(design, i_f[1:], rcond=None)
    return _rl_from_arx(float(a), float(b), dt)


def derivative_ls_field(vf: np.ndarray, i_f: np.ndarray, dt: float) -> tuple[float, float]:
    """Least squares of ``vf = R*if + L*dif/dt``, derivative by differences.

    With ``vf`` held over each period, the consistent pairing is the period's
    mean current and its difference quotient (the trapezoidal rule).
    """
    design = np.column_stack([0.5 * (i_f[1:] + i_f[:-1]), np.diff(i_f) / dt])
    (r, ell), *_ = np.linalg.lstsq(design, vf[:-1], rcond=None)
    return float(r), float(ell)


@njit(cache=True)
def _rls(regressors: np.ndarray, target: np.ndarray, forgetting: float) -> np.ndarray:
    n, p = regressors.shape
    theta = np.zeros(p)
    cov = np.eye(p) * 1e6
    for k in range(n):
        phi = regressors[k]
        pphi = cov @ phi
        gain = pphi / (forgetting + phi @ pphi)
        theta = theta + gain * (target[k] - phi @ theta)
        cov = (cov - np.outer(gain, pphi)) / forgetting
    return theta


#: Forgetting factor of the recursive least squares (memory ~1/(1-lambda) samples).
RLS_FORGETTING = 0.999


def arx_rls_field(vf: np.ndarray, i_f: np.ndarray, dt: float) -> tuple[float, float]:
    """Recursive least squares of the ARX form; the estimate at the window's end."""
    design = np.ascontiguousarray(np.column_stack([i_f[:-1], vf[:-1]]))
    a, b = _rls(design, np.ascontiguousarray(i_f[1:]), RLS_FORGETTING)
    return _rl_from_arx(float(a), float(b), dt)


def arx_ls_armature(
    va: np.ndarray, ia: np.ndarray, i_f: np.ndarray, omega: np.ndarray, dt: float
) -> tuple[float, float, float]:
    """Least squares of ``ia[k+1] = a*ia[k] + b*va[k] - b*K*e[k]``, ``e = mean(if*omega)``."""
    emf = kernels.emf_input(i_f, omega)
    design = np.column_stack([ia[:-1], va[:-1], -emf[:-1]])
    (a, b, bk), *_ = np.linalg.lstsq(design, ia[1:], rcond=None)
    r, ell = _rl_from_arx(float(a), float(b), dt)
    return r, ell, float(bk / b) if b else math.nan


def derivative_ls_armature(
    va: np.ndarray, ia: np.ndarray, i_f: np.ndarray, omega: np.ndarray, dt: float
) -> tuple[float, float, float]:
    """Least squares of ``va = Ra*ia + La*dia/dt + K*if*omega`` (trapezoidal pairing)."""
    emf = kernels.emf_input(i_f, omega)
    design = np.column_stack([0.5 * (ia[1:] + ia[:-1]), np.diff(ia) / dt, emf[:-1]])
    (r, ell, k), *_ = np.linalg.lstsq(design, va[:-1], rcond=None)
    return float(r), float(ell), float(k)


# ------------------------------------------------------- output error, scipy


def field_residual(theta: np.ndarray, vf: np.ndarray, i_f: np.ndarray, dt: float) -> np.ndarray:
    """Output-error residual for ``theta = (ln R, ln L, i0)``."""
    return i_f - kernels.simulate_rl(math.exp(theta[0]), math.exp(theta[1]), theta[2], vf, dt)


def least_squares_field(
    vf: np.ndarray, i_f: np.ndarray, dt: float, start: tuple[float, float]
) -> tuple[float, float, int]:
    """:func:`scipy.optimize.least_squares` (Levenberg-Marquardt) of eq. (1) from ``start``.

    Returns ``R, L`` and the number of residual evaluations (each one simulation
    of the window; for ``method="lm"`` scipy's count includes the finite-difference
    Jacobian's).
    """
    from scipy.optimize import least_squares

    if not all(math.isfinite(x) and x > 0 for x in start):
        return math.nan, math.nan, 0
    x0 = np.array([math.log(start[0]), math.log(start[1]), float(i_f[0])])
    sol = least_squares(field_residual, x0, args=(vf, i_f, dt), method="lm")
    return math.exp(sol.x[0]), math.exp(sol.x[1]), int(sol.nfev)


def differential_evolution_field(
    cost: Callable[[np.ndarray], np.ndarray],
    log_bounds: np.ndarray,
    *,
    population: int,
    iterations: int,
    seed: int,
) -> tuple[float, float, int]:
    """:func:`scipy.optimize.differential_evolution` on the compiled swarm cost, same budget.

    ``population`` members for ``iterations`` generations after the initial one
    (``(iterations + 1) * population`` evaluations), no polish, no early stop.
    """
    from scipy.optimize import differential_evolution

    dims = log_bounds.shape[0]
    evaluations = 0

    def vectorised(x: np.ndarray) -> np.ndarray:
        nonlocal evaluations
        evaluations += x.shape[1]
        return cost(np.ascontiguousarray(x.T))

    sol = differential_evolution(
        vectorised,
        log_bounds,
        popsize=max(1, population // dims),
        maxiter=iterations,
        tol=0.0,
        polish=False,
        vectorized=True,
        updating="deferred",
        rng=seed,
    )
    r, ell = (float(v) for v in 10.0**sol.x)
    return r, ell, evaluations


# ------------------------------------------------------------ pyswarms peer


def numpy_field_cost(
    vf: np.ndarray, i_f: np.ndarray, dt: float
) -> Callable[[np.ndarray], np.ndarray]:
    """Eq. (1) as a numpy user writes it: vectorised over particles, a Python loop over samples.

    It is the same cost as :func:`observer.estimation.kernels.rl_swarm_costs` (initial current
    projected out), so every optimiser minimises the same function.
    """
    n = vf.shape[0]
    y = np.asarray(i_f, dtype=np.float64)
    v = np.asarray(vf, dtype=np.float64)

    def cost(x: np.ndarray) -> np.ndarray:
        r = 10.0 ** x[:, 0]
        ell = 10.0 ** x[:, 1]
        a = np.exp(-r * dt / ell)
        b = (1.0 - a) / r
        drive = v[:, None] * b[None, :]
        forced = np.empty((n, x.shape[0]))
        forced[0] = 0.0
        f = np.zeros(x.shape[0])
        for k in range(n - 1):
            f *= a
            f += drive[k]
            forced[k + 1] = f
        d = y[:, None] - forced
        free = a[None, :] ** np.arange(n)[:, None]
        s_dg = np.einsum("kp,kp->p", d, free)
        s_gg = np.einsum("kp,kp->p", free, free)
        return np.einsum("kp,kp->p", d, d) - s_dg * s_dg / s_gg

    return cost


def lfilter_field_cost(
    vf: np.ndarray, i_f: np.ndarray, dt: float
) -> Callable[[np.ndarray], np.ndarray]:
    """Eq. (1) with :func:`scipy.signal.lfilter`: compiled over samples, Python over particles."""
    from scipy.signal import lfilter

    n = vf.shape[0]
    y = np.asarray(i_f, dtype=np.float64)
    steps = np.arange(n)

    def cost(x: np.ndarray) -> np.ndarray:
        out = np.empty(x.shape[0])
        for p in range(x.shape[0]):
            r = 10.0 ** x[p, 0]
            a = math.exp(-r * dt / 10.0 ** x[p, 1])
            b = (1.0 - a) / r
            forced = lfilter([0.0, b], [1.0, -a], vf)
            d = y - forced
            free = a**steps
            out[p] = d @ d - (d @ free) ** 2 / (free @ free)
        return out

    return cost


#: Clerc's constriction coefficients, the usual constant setting for a global-best PSO.
PYSWARMS_OPTIONS = {"c1": 1.49618, "c2": 1.49618, "w": 0.7298}


def pyswarms_available() -> bool:
    try:
        import pyswarms  # noqa: F401
    except ImportError:
        return False
    return True


def pyswarms_minimize(
    cost: Callable[[np.ndarray], np.ndarray],
    log_bounds: np.ndarray,
    *,
    n_particles: int,
    iterations: int,
    seed: int,
) -> tuple[np.ndarray, float]:
    """``pyswarms.single.GlobalBestPSO`` on ``cost``; best position and cost.

    pyswarms draws from the global numpy RNG (so it is seeded here: the only
    place the global RNG is touched) and writes ``report.log`` into the working
    directory, so it runs in a temporary one.
    """
    import pyswarms

    bounds = (log_bounds[:, 0].copy(), log_bounds[:, 1].copy())
    cwd = os.getcwd()
    # pyswarms' Reporter reconfigures the root logger (a stderr handler and a
    # file handler in the working directory) on every construction: undo that.
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    with tempfile.TemporaryDirectory(prefix="pyswarms-") as tmp:
        os.chdir(tmp)
        try:
            np.random.seed(seed)  # noqa: NPY002 - pyswarms knows only the global RNG
            optimizer = pyswarms.single.GlobalBestPSO(
                n_particles=n_particles,
                dimensions=log_bounds.shape[0],
                options=dict(PYSWARMS_OPTIONS),
                bounds=bounds,
            )
            best_cost, best_pos = optimizer.optimize(cost, iters=iterations, verbose=False)
        finally:
            os.chdir(cwd)
            for handler in root.handlers[:]:
                if handler not in handlers:
                    root.removeHandler(handler)
                    handler.close()
            root.setLevel(level)
    return np.asarray(best_pos, dtype=np.float64), float(best_cost)
