"""Levenberg-Marquardt polish of the swarm's best, and the sensitivities it and the uncertainty use.

The swarm lands near the minimum; the polish lands on it, so the Cramer-Rao
bound describes the estimate's spread. Parameters are ``(ln R, ln L,
<linear parameters>)``, bounded by the swarm's search range (:func:`log_limits`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from observer.estimation import kernels
from observer.estimation.ranges import SearchRange


def jacobian(residual: Any, theta: np.ndarray, at: np.ndarray | None = None) -> np.ndarray:
    """Sensitivities of ``residual`` at ``theta`` by central differences.

    The models are cheap (microseconds per simulation) and smooth in every
    parameter. Given ``at``, the residual at ``theta``, by forward differences:
    one residual per parameter instead of two, to a relative 1e-6 (the step),
    far below what a step of the polish or the uncertainty needs.
    """
    cols = []
    for j in range(theta.size):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        up = theta.copy()
        up[j] += h
        if at is not None:
            cols.append((residual(up) - at) / h)
            continue
        down = theta.copy()
        down[j] -= h
        cols.append((residual(up) - residual(down)) / (2 * h))
    return np.column_stack(cols)


#: What :func:`levenberg_marquardt` takes as ``residual_and_jacobian``: the residual
#: ``r``, its Jacobian ``J``, ``J'J`` and ``J'r`` at ``theta``.
ResidualAndJacobian = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def levenberg_marquardt(
    residual: Any,
    theta: np.ndarray,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    max_iterations: int = 30,
    rtol: float = 1e-8,
    step_tol: float = 1e-9,
    start: tuple[np.ndarray, np.ndarray] | None = None,
    fixed_jacobian: bool = False,
    residual_and_jacobian: ResidualAndJacobian | None = None,
    jacobian_on_trials: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimise ``|residual(theta)|^2``; return ``theta``, residual and Jacobian there.

    Sensitivities come from ``residual_and_jacobian`` where the caller has
    them (:meth:`~observer.estimation.problem.WindingProblem.residual_and_jacobian`:
    exact, in the residual's own pass; every trial step evaluates it, and an
    accepted one keeps its Jacobian; without ``jacobian_on_trials`` a trial
    takes ``residual`` alone and an accepted step then
    ``residual_and_jacobian``: for a Jacobian with costly columns, which a
    rejected trial would waste), else from :func:`jacobian` (forward
    differences, one residual per parameter after every accepted step). Steps
    are kept inside ``[lower, upper]`` (the swarm's search range): in a window
    that does not identify a parameter the cost is flat along it, and an
    unbounded step would run ``log L`` to overflow.

    ``start``, the residual and Jacobian at ``theta`` when the caller has them,
    saves their evaluation. With ``fixed_jacobian`` that Jacobian serves every
    step (the chord method: one residual per step instead of ``1 + 2p``) and
    is the one returned: for a refit that moves ``theta`` by little, where the
    sensitivities barely change (see
    :func:`observer.estimation.stages.specification_stage`).
    """
    lo = np.full(theta.size, -np.inf) if lower is None else lower
    hi = np.full(theta.size, np.inf) if upper is None else upper
    exact = residual_and_jacobian if not fixed_jacobian else None
    if start is not None:
        r, jac = start
        jtj, grad = _normal_equations(jac, r)
    elif exact is not None:
        r, jac, jtj, grad = exact(theta)
    else:
        r = residual(theta)
        jac = jacobian(residual, theta, r)
        jtj, grad = _normal_equations(jac, r)
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(max_iterations):
        # A parameter on its limit whose descent points outwards stays there (active set):
        # a step computed with it free and then clipped overshoots the others.
        free = ~(((theta >= hi) & (grad < 0)) | ((theta <= lo) & (grad > 0)))
        if not free.any():
            break
        jtj_free = jtj[np.ix_(free, free)]
        grad_free = grad[free]
        curvature = np.maximum(np.diag(jtj_free), 1e-300)
        diagonal = np.diag_indices(jtj_free.shape[0])
        # What the undamped step would gain at best (Gauss-Newton): nothing worth a
        # residual means theta is the minimum already (a refit starting on its
        # optimum), where the damped trials below would fail one after another.
        if _gauss_newton_gain(jtj_free, grad_free) < rtol * cost:
            break
        improved = False
        for _ in range(12):
            # Marquardt's scaling: damp each direction by its own curvature.
            a = jtj_free.copy()
            a[diagonal] += damping * curvature
            try:
                step = np.zeros(theta.size)
                step[free] = -np.linalg.solve(a, grad_free)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            trial = np.minimum(np.maximum(theta + step, lo), hi)
            outcome = _trial(residual, exact if jacobian_on_trials else None, trial)
            if outcome is None:
                damping *= 10
                continue
            cost_trial, evaluated = outcome
            if cost_trial < cost:
                improved = True
                break
            damping *= 10
        if not improved:
            break
        relative_gain = (cost - cost_trial) / max(cost, 1e-300)
        moved = max(
            abs(t - th) / max(abs(th), 1.0)
            for t, th in zip(trial.tolist(), theta.tolist(), strict=True)
        )
        theta, r, cost = trial, evaluated[0], cost_trial
        if exact is not None and jacobian_on_trials:
            _, jac, jtj, grad = evaluated
        elif exact is not None:
            r, jac, jtj, grad = exact(theta)
            cost = float(r @ r)
        elif fixed_jacobian:
            grad = jac.T @ r
        else:
            jac = jacobian(residual, theta, r)
            jtj, grad = _normal_equations(jac, r)
        damping = max(damping / 10, 1e-9)
        # Converged, or creeping along a direction the window does not identify
        # (flat cost, e.g. Lf under constant field voltage): more steps buy nothing.
        if relative_gain < rtol or moved < step_tol:
            break
    return theta, r, jac


def _normal_equations(jac: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J'J`` and ``J'r``; the first by the uncertainty's kernel (BLAS takes twice as long
    over a tall ``J`` of two to five columns)."""
    jtj, _ = kernels.score_products(
        np.ascontiguousarray(jac, dtype=np.float64), np.ascontiguousarray(r, dtype=np.float64), 0
    )
    return jtj, jac.T @ r


#: Machine epsilon: lstsq's default cutoff is this times the matrix's size, relative.
_EPS = float(np.finfo(np.float64).eps)


def _gauss_newton_gain(jtj: np.ndarray, grad: np.ndarray) -> float:
    """``grad' pinv(J'J) grad``: how much the undamped step would lower the cost at best.

    The pseudo-inverse as :func:`numpy.linalg.lstsq` takes it (singular values
    below ``eps * size`` of the largest dropped): a direction the window does
    not identify (flat cost) adds nothing. ``J'J`` is symmetric, so its
    eigenvalues are its singular values; ``eigh`` costs half of ``lstsq``.
    """
    try:
        values, vectors = np.linalg.eigh(jtj)
    except np.linalg.LinAlgError:
        return math.inf
    # A handful of parameters: Python floats beat numpy's per-call overhead.
    lam = values.tolist()
    if not all(math.isfinite(v) for v in lam):
        return math.inf  # as lstsq, which fails on them: no verdict, take a step
    cutoff = _EPS * len(lam) * max(abs(lam[0]), abs(lam[-1]))  # eigh sorts them
    along = (grad @ vectors).tolist()
    return float(sum(g * g / v for g, v in zip(along, lam, strict=True) if abs(v) > cutoff))


def _trial(
    residual: Any, exact: ResidualAndJacobian | None, theta: np.ndarray
) -> tuple[float, tuple[np.ndarray, ...]] | None:
    """The cost and residual at a trial ``theta`` (with the Jacobian where ``exact`` gives it),
    or None where it does not exist: an overflow, or a residual that is not finite."""
    try:
        with np.errstate(all="ignore"):
            evaluated = (residual(theta),) if exact is None else exact(theta)
            # A sum of squares is finite exactly where every term is (or it overflows: a
            # trial that could not lower the cost anyway).
            cost = float(evaluated[0] @ evaluated[0])
    except (OverflowError, ZeroDivisionError, FloatingPointError):
        return None
    return (cost, evaluated) if math.isfinite(cost) else None


def log_limits(bounds: SearchRange, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Limits of ``(ln R, ln L, <free linear parameters>)`` from a search range."""
    lower = np.full(size, -np.inf)
    upper = np.full(size, np.inf)
    lower[:2] = np.log([bounds.resistance_ohm[0], bounds.inductance_h[0]])
    upper[:2] = np.log([bounds.resistance_ohm[1], bounds.inductance_h[1]])
    return lower, upper
