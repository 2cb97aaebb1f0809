"""Levenberg-Marquardt polish of the swarm's best, and the sensitivities it and the uncertainty use.

The swarm lands near the minimum; the polish lands on it, so the Cramer-Rao
bound describes the estimate's spread. Parameters are ``(ln R, ln L,
<linear parameters>)``, bounded by the swarm's search range (:func:`log_limits`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

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
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimise ``|residual(theta)|^2``; return ``theta``, residual and Jacobian there.

    Sensitivities come from ``residual_and_jacobian`` where the caller has
    them (:meth:`~observer.estimation.problem.WindingProblem.residual_and_jacobian`:
    exact, in the residual's own pass; every trial step evaluates it, and an
    accepted one keeps its Jacobian), else from :func:`jacobian` (forward
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

    def safe(th: np.ndarray) -> tuple[np.ndarray, ...] | None:
        try:
            with np.errstate(all="ignore"):
                out = (residual(th),) if exact is None else exact(th)
        except (OverflowError, ZeroDivisionError, FloatingPointError):
            return None
        return out if np.all(np.isfinite(out[0])) else None

    if start is not None:
        r, jac = start
    elif exact is not None:
        r, jac, _, _ = exact(theta)
    else:
        r = residual(theta)
        jac = jacobian(residual, theta, r)
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(max_iterations):
        jtj = jac.T @ jac
        grad = jac.T @ r
        scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
        # What the undamped step would gain at best (Gauss-Newton): nothing worth a
        # residual means theta is the minimum already (a refit starting on its
        # optimum), where the damped trials below would fail one after another.
        try:
            within = float(grad @ np.linalg.lstsq(jtj, grad, rcond=None)[0]) < rtol * cost
        except np.linalg.LinAlgError:
            within = False
        if within:
            break
        improved = False
        for _ in range(12):
            # Marquardt's scaling: damp each direction by its own curvature.
            a = jtj + damping * np.diag(scale**2)
            try:
                step = -np.linalg.solve(a, grad)
            except np.linalg.LinAlgError:
                damping *= 10
                continue
            trial = np.clip(theta + step, lo, hi)
            evaluated = safe(trial)
            if evaluated is None:
                damping *= 10
                continue
            r_trial = evaluated[0]
            jac_trial = evaluated[1] if exact is not None else jac
            cost_trial = float(r_trial @ r_trial)
            if cost_trial < cost:
                improved = True
                break
            damping *= 10
        if not improved:
            break
        relative_gain = (cost - cost_trial) / max(cost, 1e-300)
        moved = float(np.max(np.abs(trial - theta) / np.maximum(np.abs(theta), 1.0)))
        theta, r, cost = trial, r_trial, cost_trial
        if exact is not None:
            jac = jac_trial
        elif not fixed_jacobian:
            jac = jacobian(residual, theta, r)
        damping = max(damping / 10, 1e-9)
        # Converged, or creeping along a direction the window does not identify
        # (flat cost, e.g. Lf under constant field voltage): more steps buy nothing.
        if relative_gain < rtol or moved < step_tol:
            break
    return theta, r, jac


def log_limits(bounds: SearchRange, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Limits of ``(ln R, ln L, <free linear parameters>)`` from a search range."""
    lower = np.full(size, -np.inf)
    upper = np.full(size, np.inf)
    lower[:2] = np.log([bounds.resistance_ohm[0], bounds.inductance_h[0]])
    upper[:2] = np.log([bounds.resistance_ohm[1], bounds.inductance_h[1]])
    return lower, upper
