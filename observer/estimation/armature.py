"""The armature's estimator: ``(Ra, La, K)`` from ``va, ia`` and the measured ``if, omega``.

:func:`estimate_armature` runs four stages, each a function that can be read
and tested alone:

1. :func:`armature_swarm` -- the paper's swarm over ``log10 (Ra, La)``, with
   ``K`` and the initial current solved in closed form for every particle;
2. :func:`polish_armature` -- Levenberg-Marquardt on ``(ln Ra, ln La, i0[, K])``
   from the swarm's best, and the Jacobian there;
3. :func:`eiv_compensation` -- the errors-in-variables correction: noise on the
   measured voltages biases output error towards a lower model gain; its
   variance is read from the residual, its expected share of eq. (1)
   subtracted and the swarm re-run near the plain estimate;
4. :func:`armature_std` -- the uncertainty: the sandwich bound at the polished
   optimum, combined with how far input noise could have moved the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from observer.estimation import kernels
from observer.estimation.polish import jacobian, levenberg_marquardt, log_limits
from observer.estimation.pso import CostFunction, ParticleSwarm, PSOResult
from observer.estimation.ranges import (
    SearchRange,
    armature_search_range,
    check_signals,
    kernel_array,
)
from observer.estimation.result import CircuitEstimate
from observer.estimation.swarm import run_swarm
from observer.estimation.uncertainty import crlb_std, input_noise_variance

#: The errors-in-variables refinement searches within this factor of the plain estimate.
_COMPENSATION_FACTOR = 1.5


@dataclass(frozen=True)
class ArmatureWindow:
    """One window's armature signals, as the kernels take them.

    Attributes
    ----------
    va, ia, i_f, omega : (n,) arrays
        Armature voltage (V, held over each period), armature current (A), field
        current (A) and speed (rad/s): writable contiguous float64 (see
        :func:`~observer.estimation.ranges.kernel_array`).
    emf : (n,) array
        Per-period mean of ``if*omega`` (A*rad/s), see
        :func:`~observer.estimation.kernels.emf_input`.
    dt : float
        Sample period (s).
    emf_constant : float or None
        ``K`` held at this value (V*s/(rad*A)), or None to fit it.
    """

    va: np.ndarray
    ia: np.ndarray
    i_f: np.ndarray
    omega: np.ndarray
    emf: np.ndarray
    dt: float
    emf_constant: float | None = None

    @classmethod
    def from_signals(
        cls,
        va: np.ndarray,
        ia: np.ndarray,
        i_f: np.ndarray,
        omega: np.ndarray,
        dt: float,
        emf_constant: float | None = None,
    ) -> ArmatureWindow:
        """Check the signals (raising ``EstimationError``) and wrap them."""
        va = kernel_array(va)
        ia = kernel_array(ia)
        i_f = kernel_array(i_f)
        omega = kernel_array(omega)
        check_signals(va=va, ia=ia, i_f=i_f, omega=omega)
        return cls(va, ia, i_f, omega, kernels.emf_input(i_f, omega), dt, emf_constant)

    @property
    def n_samples(self) -> int:
        return int(self.va.shape[0])

    @property
    def fit_k(self) -> bool:
        """Whether ``K`` is fitted (not held)."""
        return self.emf_constant is None

    def swarm_cost(self, input_noise_var: float = 0.0) -> CostFunction:
        """Eq. (1) for a whole swarm over ``log10 (Ra, La)``, input noise compensated if given."""
        k_arg = math.nan if self.emf_constant is None else float(self.emf_constant)

        def cost(x: np.ndarray) -> np.ndarray:
            return kernels.armature_swarm_costs(
                x, self.va, self.emf, self.ia, self.dt, True, k_arg, input_noise_var
            )

        return cost

    def linear(self, resistance: float, inductance: float) -> tuple[float, float, np.ndarray]:
        """Best ``(K, i0)`` (``K`` held if given) and the residual for given ``(R, L)``."""
        va, emf, ia, dt, emf_constant = self.va, self.emf, self.ia, self.dt, self.emf_constant
        zeros = np.zeros_like(va)
        free = kernels.simulate_rl(resistance, inductance, 1.0, zeros, dt)
        if emf_constant is not None:
            forced = kernels.simulate_armature(
                resistance, inductance, emf_constant, 0.0, va, emf, dt
            )
            d = ia - forced
            i0 = float(d @ free) / float(free @ free)
            return emf_constant, i0, d - i0 * free
        forced = kernels.simulate_rl(resistance, inductance, 0.0, va, dt)
        forced_emf = kernels.simulate_rl(resistance, inductance, 0.0, emf, dt)
        basis = np.column_stack([-forced_emf, free])
        coef, *_ = np.linalg.lstsq(basis, ia - forced, rcond=None)
        return float(coef[0]), float(coef[1]), ia - forced - basis @ coef


@dataclass(frozen=True)
class ArmaturePoint:
    """Armature parameters at one point and the current residual (A) there."""

    resistance_ohm: float
    inductance_h: float
    emf_constant_h: float
    initial_current_a: float
    residual: np.ndarray


@dataclass(frozen=True)
class PolishedArmature:
    """The polished fit: its point, ``theta = (ln R, ln L, i0[, K])`` and the Jacobian there."""

    point: ArmaturePoint
    theta: np.ndarray
    jacobian: np.ndarray


@dataclass(frozen=True)
class EivCorrection:
    """Outcome of the errors-in-variables compensation.

    Attributes
    ----------
    point : ArmaturePoint
        The compensated estimate, or the plain one when no input noise was
        found or the correction was refused.
    input_noise_var : float
        Variance (V^2) of the input noise compensated (0 when refused).
    bias_bound : (3,) array
        How far input noise could have moved ``R, L, K`` (ohm, H, V*s/(rad*A)).
    """

    point: ArmaturePoint
    input_noise_var: float
    bias_bound: np.ndarray


def armature_swarm(
    window: ArmatureWindow,
    search_range: SearchRange,
    *,
    n_particles: int,
    max_iterations: int,
    schedule: str | tuple[float, float],
    w: float,
    rng: np.random.Generator,
    x0: tuple[float, float] | None,
    init_range: SearchRange | None,
    explore_fraction: float,
    tol: float,
) -> PSOResult:
    """Stage 1: the swarm over ``log10 (Ra, La)``, ``K`` and ``i0`` projected out per particle."""
    return run_swarm(
        window.swarm_cost(), search_range, n_particles=n_particles,
        max_iterations=max_iterations, schedule=schedule, w=w, rng=rng, x0=x0,
        init_range=init_range, explore_fraction=explore_fraction, tol=tol,
    )  # fmt: skip


def polish_armature(
    window: ArmatureWindow, result: PSOResult, bounds: SearchRange, *, polish: bool = True
) -> PolishedArmature:
    """Stage 2: Levenberg-Marquardt from the swarm's best (``polish`` off: only the Jacobian)."""
    resistance, inductance = (float(v) for v in 10.0**result.x)
    k_value, i0, resid = window.linear(resistance, inductance)
    fit_k = window.fit_k
    va, emf, ia, dt = window.va, window.emf, window.ia, window.dt

    def residual(theta: np.ndarray) -> np.ndarray:
        r_, l_ = math.exp(theta[0]), math.exp(theta[1])
        k_ = theta[3] if fit_k else k_value
        return ia - kernels.simulate_armature(r_, l_, k_, theta[2], va, emf, dt)

    theta = np.array(
        [math.log(resistance), math.log(inductance), i0] + ([k_value] if fit_k else [])
    )
    lower, upper = log_limits(bounds, theta.size)
    if polish:
        theta, resid, jac = levenberg_marquardt(residual, theta, lower=lower, upper=upper)
    else:
        resid = residual(theta)
        jac = jacobian(residual, theta)
    point = ArmaturePoint(
        resistance_ohm=math.exp(theta[0]),
        inductance_h=math.exp(theta[1]),
        emf_constant_h=float(theta[3]) if fit_k else k_value,
        initial_current_a=float(theta[2]),
        residual=resid,
    )
    return PolishedArmature(point, theta, jac)


def eiv_compensation(
    window: ArmatureWindow,
    plain: ArmaturePoint,
    bounds: SearchRange,
    *,
    n_particles: int,
    max_iterations: int,
    schedule: str | tuple[float, float],
    w: float,
    rng: np.random.Generator,
) -> EivCorrection:
    """Stage 3: remove the errors-in-variables bias of output error from the plain estimate.

    Noise on the measured ``va`` (and on ``if*omega``) makes eq. (1) favour a
    lower model gain, overestimating ``La`` by several percent at 0.2 % sensor
    noise and 2 kHz. The noise variance is read from the residual's
    autocorrelation (:func:`~observer.estimation.uncertainty.input_noise_variance`),
    its expected share of eq. (1) subtracted, and the swarm re-run in a narrow
    range around ``plain``.
    """
    a_, b_ = kernels.zoh_coefficients(plain.resistance_ohm, plain.inductance_h, window.dt)
    noise_var = input_noise_variance(plain.residual, a_, b_)
    if not noise_var > 0.0:
        return EivCorrection(plain, noise_var, np.zeros(3))
    plain_values = np.array([plain.resistance_ohm, plain.inductance_h, plain.emf_constant_h])
    # The correction is a few percent: search only near the plain estimate. An
    # overestimated noise variance makes the compensated cost fall without
    # bound towards La -> 0 (gain 1/R), a spurious minimum the full range holds.
    local = bounds.around(
        plain.resistance_ohm, plain.inductance_h, _COMPENSATION_FACTOR
    ).log_bounds()
    swarm = ParticleSwarm(
        window.swarm_cost(noise_var), local, n_particles=max(20, n_particles // 2), w=w,
        schedule=schedule, x0=np.log10([plain.resistance_ohm, plain.inductance_h]), rng=rng,
    )  # fmt: skip
    refined = swarm.run(max(30, max_iterations))
    margin = np.minimum(refined.x - local[:, 0], local[:, 1] - refined.x)
    resistance, inductance = (float(v) for v in 10.0**refined.x)
    k_value, i0, resid = window.linear(resistance, inductance)
    moved = np.abs(np.array([resistance, inductance, k_value]) - plain_values)
    if np.all(margin > 0.01 * np.log10(_COMPENSATION_FACTOR)):
        # The Cramer-Rao bound ignores input noise; the size of the correction
        # bounds how far input noise could have moved the estimate.
        corrected = ArmaturePoint(resistance, inductance, k_value, i0, resid)
        return EivCorrection(corrected, noise_var, 0.5 * moved)
    # Pressed against the edge: the compensation model does not fit this
    # window (weak excitation, or unmodelled physics read as input noise).
    # Keep the plain fit. La may be off by as much as the box; R and K by
    # as much as the refused correction would have moved them (usually
    # little: it is La that input noise biases).
    moved[1] = max(moved[1], (_COMPENSATION_FACTOR - 1.0) * abs(plain_values[1]))
    return EivCorrection(plain, 0.0, moved)


def armature_std(
    window: ArmatureWindow, fit: PolishedArmature, eiv: EivCorrection
) -> dict[str, float]:
    """Stage 4: one-sigma uncertainty of ``R, L, K`` of the final estimate.

    The sandwich bound at the polished optimum
    (:func:`~observer.estimation.uncertainty.crlb_std`, relative in ``R`` and
    ``L``), combined with the bound on the errors-in-variables bias.
    """
    theta = fit.theta
    std = crlb_std(fit.jacobian, fit.point.residual, math.exp(theta[1] - theta[0]) / window.dt)
    point = eiv.point
    fit_k = window.fit_k
    stds_ = np.hypot(
        np.array(
            [point.resistance_ohm * std[0], point.inductance_h * std[1], std[3] if fit_k else 0.0]
        ),
        eiv.bias_bound,
    )
    return {"R": float(stds_[0]), "L": float(stds_[1]), "K": float(stds_[2]) if fit_k else 0.0}


def estimate_armature(
    va: np.ndarray,
    ia: np.ndarray,
    i_f: np.ndarray,
    omega: np.ndarray,
    dt: float,
    *,
    emf_constant: float | None = None,
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
    compensate_input_noise: bool = True,
) -> CircuitEstimate:
    """Estimate ``(Ra, La, K)`` of the armature from ``va, ia`` and measured ``if, omega``.

    Parameters
    ----------
    va, ia, i_f, omega : (n,) arrays
        Armature voltage (V, held over each period), armature current (A), field
        current (A) and speed (rad/s).
    dt : float
        Sample period (s).
    emf_constant : float, optional
        Hold ``K`` at this value instead of fitting it (a window without speed).
    compensate_input_noise : bool
        Remove the errors-in-variables bias of output error: noise on the
        measured ``va`` (and on ``if*omega``) makes eq. (1) favour a lower
        model gain, overestimating ``La`` by several percent at 0.2 % sensor
        noise and 2 kHz. The noise variance is read from the residual's
        autocorrelation (:func:`input_noise_variance`), its expected share of
        eq. (1) subtracted, and the swarm re-run in a narrow range.
    Other parameters
        As for :func:`estimate_field`.
    """
    window = ArmatureWindow.from_signals(va, ia, i_f, omega, dt, emf_constant)
    rng_ = np.random.default_rng(rng)
    bounds = (
        search_range
        if search_range is not None
        else armature_search_range(window.va, window.ia, window.i_f, window.omega, dt)
    )
    result = armature_swarm(
        window, bounds, n_particles=n_particles, max_iterations=max_iterations,
        schedule=schedule, w=w, rng=rng_, x0=x0, init_range=init_range,
        explore_fraction=explore_fraction, tol=tol,
    )  # fmt: skip
    fit = polish_armature(window, result, bounds, polish=polish)
    if compensate_input_noise:
        eiv = eiv_compensation(
            window, fit.point, bounds, n_particles=n_particles, max_iterations=max_iterations,
            schedule=schedule, w=w, rng=rng_,
        )  # fmt: skip
    else:
        eiv = EivCorrection(fit.point, 0.0, np.zeros(3))
    point = eiv.point
    return CircuitEstimate(
        circuit="armature",
        resistance_ohm=point.resistance_ohm,
        inductance_h=point.inductance_h,
        emf_constant_h=point.emf_constant_h,
        initial_current_a=point.initial_current_a,
        rms_a=float(np.sqrt(np.mean(point.residual * point.residual))),
        std=armature_std(window, fit, eiv),
        n_samples=window.n_samples,
        search_range=bounds,
        pso=result,
        polished=polish,
        input_noise_var=eiv.input_noise_var,
    )
