"""The field winding's estimator: ``(Rf, Lf)`` from ``vf`` and ``if``.

Swarm over ``log10 (R, L)`` with the initial current projected out
(:func:`observer.estimation.kernels.rl_swarm_costs`), Levenberg-Marquardt polish
on ``(ln R, ln L, i0)``, and the uncertainty at the optimum.
"""

from __future__ import annotations

import math

import numpy as np

from observer.estimation import kernels
from observer.estimation.polish import jacobian, levenberg_marquardt, log_limits
from observer.estimation.ranges import SearchRange, check_signals, field_search_range, kernel_array
from observer.estimation.result import CircuitEstimate
from observer.estimation.swarm import run_swarm
from observer.estimation.uncertainty import crlb_std


def _field_linear(
    resistance: float, inductance: float, vf: np.ndarray, i_f: np.ndarray, dt: float
) -> tuple[float, np.ndarray]:
    """Best initial current and the residual for given ``(R, L)``."""
    forced = kernels.simulate_rl(resistance, inductance, 0.0, vf, dt)
    free = kernels.simulate_rl(resistance, inductance, 1.0, np.zeros_like(vf), dt)
    d = i_f - forced
    i0 = float(d @ free) / float(free @ free)
    return i0, d - i0 * free


def estimate_field(
    vf: np.ndarray,
    i_f: np.ndarray,
    dt: float,
    *,
    search_range: SearchRange | None = None,
    n_particles: int = 100,
    max_iterations: int = 100,
    schedule: str | tuple[float, float] = "s-k",
    w: float = 0.7,
    rng: int | np.random.Generator | None = None,
    x0: tuple[float, float] | None = None,
    init_range: SearchRange | None = None,
    explore_fraction: float = 0.0,
    tol: float = 0.0,
    polish: bool = True,
) -> CircuitEstimate:
    """Estimate ``(Rf, Lf)`` of the field winding from ``vf`` (V) and ``if`` (A).

    Parameters
    ----------
    vf, i_f : (n,) arrays
        Field voltage, held over each sample period, and field current.
    dt : float
        Sample period (s).
    search_range : SearchRange, optional
        Defaults to :func:`field_search_range` of the data.
    n_particles, max_iterations, schedule, w, rng, tol
        Swarm settings, see :class:`observer.estimation.pso.ParticleSwarm`.
    x0, init_range, explore_fraction
        Warm start: previous ``(R, L)``, the shrunken range to initialise most
        particles in, and the fraction that still explores all of ``search_range``.
    polish : bool
        Refine the swarm's best by Levenberg-Marquardt (default). Off, the
        estimate is the swarm's alone, as in the paper.
    """
    vf = kernel_array(vf)
    i_f = kernel_array(i_f)
    n = check_signals(vf=vf, i_f=i_f)
    rng_ = np.random.default_rng(rng)
    bounds = search_range if search_range is not None else field_search_range(vf, i_f, dt)

    def cost(x: np.ndarray) -> np.ndarray:
        return kernels.rl_swarm_costs(x, vf, i_f, dt, True, 0.0)

    result = run_swarm(
        cost, bounds, n_particles=n_particles, max_iterations=max_iterations,
        schedule=schedule, w=w, rng=rng_, x0=x0, init_range=init_range,
        explore_fraction=explore_fraction, tol=tol,
    )  # fmt: skip
    resistance, inductance = (float(v) for v in 10.0**result.x)
    i0, resid = _field_linear(resistance, inductance, vf, i_f, dt)

    def residual(theta: np.ndarray) -> np.ndarray:
        r_, l_ = math.exp(theta[0]), math.exp(theta[1])
        return i_f - kernels.simulate_rl(r_, l_, theta[2], vf, dt)

    theta = np.array([math.log(resistance), math.log(inductance), i0])
    lower, upper = log_limits(bounds, theta.size)
    if polish:
        theta, resid, jac = levenberg_marquardt(residual, theta, lower=lower, upper=upper)
    else:
        resid = residual(theta)
        jac = jacobian(residual, theta)
    std_log = crlb_std(jac, resid, math.exp(theta[1] - theta[0]) / dt)
    resistance, inductance, i0 = math.exp(theta[0]), math.exp(theta[1]), float(theta[2])
    return CircuitEstimate(
        circuit="field",
        resistance_ohm=resistance,
        inductance_h=inductance,
        emf_constant_h=None,
        initial_current_a=i0,
        rms_a=float(np.sqrt(np.mean(resid * resid))),
        std={"R": resistance * std_log[0], "L": inductance * std_log[1]},
        n_samples=n,
        search_range=bounds,
        pso=result,
        polished=polish,
    )
