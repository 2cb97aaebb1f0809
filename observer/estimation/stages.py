"""The stages every winding estimate goes through, each a function that can be tested alone.

1. :func:`swarm_stage` -- the paper's swarm over ``log10 (R, L)``; ``K`` and the
   segments' initial currents solved in closed form for every particle;
2. :func:`polish_stage` -- Levenberg-Marquardt on ``(ln R, ln L[, K][, shift])``
   from the swarm's best (``shift``: the relative delay of the voltage channel),
   and the Jacobian there;
3. :func:`eiv_stage` -- the errors-in-variables correction: noise on the
   measured voltage biases output error towards a lower model gain; its
   variance is read from the residual, its expected share of eq. (1)
   subtracted and the minimum of what remains found near the plain estimate;
4. :func:`std_stage` -- the uncertainty: the sandwich bound at the optimum,
   combined with how far input noise could have moved the estimate.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from observer.estimation import intersample_kernels as ik
from observer.estimation.frontend import (
    MISMATCH_SHAPE,
    MISMATCH_SHAPES,
    MISMATCH_UNDERSEEN,
)
from observer.estimation.intersample import Segments, mains_ripple_share, smooth_moments
from observer.estimation.polish import jacobian, levenberg_marquardt
from observer.estimation.problem import WindingProblem
from observer.estimation.pso import CostFunction, ParticleSwarm, PSOResult
from observer.estimation.ranges import SearchRange
from observer.estimation.swarm import run_swarm
from observer.estimation.uncertainty import crlb_std, input_noise_variance

#: The errors-in-variables refinement searches within this factor of the plain estimate.
COMPENSATION_FACTOR = 1.5

#: ``smooth`` replaces ``hold`` only when it lowers eq. (1) by this many residual
#: variances: one extra parameter (the shift) alone lowers it by about one.
SMOOTH_OVER_HOLD = 25.0

#: White-noise draws over which :func:`averaged_noise` averages a model's noise gain
#: (fixed draws: the same window always gives the same decision, so replay is exact).
NOISE_DRAWS = 4

#: Relative uncertainty no window of a *measured* voltage (every model but
#: ``hold``) goes below: the reconstruction between samples and the front ends
#: leave systematic errors of this size on simulated converter chains (K
#: 0.03-0.1 %, La 0.3-0.5 % at 5 kHz) that no noise term describes, and a real
#: winding adds its own (R warming over the window, L following the current).
#: A held voltage is the drive's own reference, exact by construction.
MODEL_FLOOR = {"R": 0.001, "L": 0.002, "K": 0.0005}

#: An armature voltage offset of this share of the window's mean |va| is assumed
#: possible: a voltage sensor's offset (0.1-0.5 % of its range, about twice the
#: rated voltage) or the brush drop (1-2 V at any current) that a drive's
#: reference voltage does not show.
OFFSET_SHARE = 0.001

#: Untold front ends: the EMF's timing against the current's, one-sigma, in sample periods.
#: A multiplexed ADC samples its channels one after another within a period (an encoder's
#: speed taken over a period lags by half of one); the voltage's delay behind the current is
#: fitted (``shift``), the speed's is not, and the EMF read that late errs by
#: ``K*if*domega/dt`` times it. On the 60 V traction motor (small inertia) at 2 kHz with the
#: speed sampled half a period after the current, 7 % of the published Ra windows were
#: outside 2.5 std; the P-12 behind the bench's ``thyristor-skew`` ADC, 12 %.
SPEED_DELAY_PRIOR = 0.5

#: A voltage with transitions (jumps, filtered or not) in this share of its intervals is a
#: converter's measured voltage, never a drive's held reference: a 6-pulse bridge at 5 kHz
#: shows them in ~15 % of intervals, a reference only at its rare setpoint steps.
CONVERTER_TRANSITIONS = 0.02

#: A voltage with this share of its fluctuation at mains harmonics
#: (:func:`~observer.estimation.intersample.mains_ripple_share`) is a line-commutated
#: converter's measured terminals, even where a filter at 2 kHz hides the jumps
#: themselves; a held reference or white noise puts about none there.
CONVERTER_RIPPLE = 0.25

#: A cubic read this many periods late imitates a held voltage (sample periods),
#: within ``HOLD_SHIFT_WIDTH``.
HOLD_SHIFT = -0.5
HOLD_SHIFT_WIDTH = 0.2


@dataclass(frozen=True)
class SwarmSettings:
    """The swarm's settings, as :func:`observer.estimation.estimate_field` takes them."""

    n_particles: int = 100
    max_iterations: int = 100
    schedule: str | tuple[float, float] = "s-k"
    w: float = 0.7
    x0: tuple[float, float] | None = None
    init_range: SearchRange | None = None
    explore_fraction: float = 0.0
    tol: float = 0.0


@dataclass(frozen=True)
class WindingPoint:
    """Parameters at one point and the current residual (A) there.

    Attributes
    ----------
    resistance_ohm, inductance_h : float
    emf_constant_h : float
        ``K`` (armature; 0 for the field).
    shift : float
        Relative delay of the voltage channel behind the current (sample periods).
    initial_current_a : float
        Fitted current at the first segment's first sample.
    residual : array
    """

    resistance_ohm: float
    inductance_h: float
    emf_constant_h: float
    shift: float
    initial_current_a: float
    residual: np.ndarray
    lag: float = 0.0

    def values(self) -> np.ndarray:
        return np.array([self.resistance_ohm, self.inductance_h, self.emf_constant_h])


@dataclass(frozen=True)
class PolishedFit:
    """The polished fit: its point, ``theta`` and the Jacobian there."""

    point: WindingPoint
    theta: np.ndarray
    jacobian: np.ndarray

    @functools.cached_property
    def qr(self) -> tuple[np.ndarray, np.ndarray]:
        """The Jacobian's QR factors, computed once: every nuisance column measured beside
        it (the jumps' area, the offset, the EMF's timing, the voltage errors' moves) solves
        against the same Jacobian (0.3 ms a factorisation at 10 kHz)."""
        q, r = np.linalg.qr(self.jacobian)
        return q, r


@dataclass(frozen=True)
class EivCorrection:
    """Outcome of the errors-in-variables compensation.

    Attributes
    ----------
    point : WindingPoint
        The compensated estimate, or the plain one when no input noise was
        found or the correction was refused.
    input_noise_var : float
        Variance (V^2) of the input noise compensated (0 when refused).
    bias_bound : (3,) array
        How far input noise could have moved ``R, L, K`` (ohm, H, V*s/(rad*A)).
    """

    point: WindingPoint
    input_noise_var: float
    bias_bound: np.ndarray


def point_at(
    problem: WindingProblem, resistance: float, inductance: float, shift: float
) -> WindingPoint:
    """The point at ``(R, L, shift)`` with ``K`` and the initial currents solved for."""
    k = problem.best_k(resistance, inductance, shift)
    resid, initial = problem.evaluate(resistance, inductance, k, shift)
    i0 = float(initial[0]) if initial.size else 0.0
    return WindingPoint(resistance, inductance, k, shift, i0, resid, problem.lag)


def swarm_stage(
    problem: WindingProblem,
    bounds: SearchRange,
    settings: SwarmSettings,
    rng: np.random.Generator,
    input_noise_var: float = 0.0,
) -> PSOResult:
    """Stage 1: the swarm over ``log10 (R, L)``."""
    return run_swarm(
        problem.swarm_cost(input_noise_var), bounds, n_particles=settings.n_particles,
        max_iterations=settings.max_iterations, schedule=settings.schedule, w=settings.w,
        rng=rng, x0=settings.x0, init_range=settings.init_range,
        explore_fraction=settings.explore_fraction, tol=settings.tol,
    )  # fmt: skip


#: A settled window's polish gets this many iterations (a warm window's takes 2-5) ...
SETTLED_ITERATIONS = 10
#: ... and must end where the undamped step gains less than this share of the cost
#: (1e-6: a hundredth of the residual variance on a window of 10^4 samples).
SETTLED_RTOL = 1e-6


def settled_stage(
    problem: WindingProblem,
    bounds: SearchRange,
    x0: tuple[float, float],
    rms_limit: float,
    *,
    polish: bool = True,
) -> tuple[PSOResult, PolishedFit] | None:
    """Stages 1 and 2 of a settled warm window: the polish from the warm start, no swarm.

    A window whose predecessors agreed with the tracked state ``x0`` has, most
    likely, the same minimum near ``x0``: Levenberg-Marquardt from there lands
    on it with one cost evaluation where the warm swarm spends 500. The
    polished fit stands when it converged within :data:`SETTLED_ITERATIONS`
    (what the undamped step could still gain is below :data:`SETTLED_RTOL` of
    the cost) and its residual's rms is at most ``rms_limit`` (the observer's
    limit for a degraded fit); None otherwise: the cost surface moved (a
    minimum far from ``x0``, crept towards in small steps), and the window
    needs its swarm.
    """
    box = bounds.log_bounds()
    x = np.clip(np.log10(np.asarray(x0, dtype=np.float64)), box[:, 0], box[:, 1])
    cost = float(problem.swarm_cost()(x[None, :])[0])
    start = PSOResult(
        x=x, cost=cost, n_iterations=0, n_evaluations=1, history=np.array([cost]),
        converged=False, message="settled: polished from the warm start without a swarm",
    )  # fmt: skip
    fit = polish_stage(problem, start, bounds, polish=polish, max_iterations=SETTLED_ITERATIONS)
    residual = fit.point.residual
    cost = float(residual @ residual)
    grad = fit.jacobian.T @ residual
    # What a step could gain where it can go: not past a limit the fit rests on.
    lower, upper = problem.limits(box)
    free = ~(((fit.theta >= upper) & (grad < 0)) | ((fit.theta <= lower) & (grad > 0)))
    jac, grad = fit.jacobian[:, free], grad[free]
    gain = float(grad @ np.linalg.lstsq(jac.T @ jac, grad, rcond=None)[0]) if grad.size else 0.0
    rms = math.sqrt(cost / max(residual.size, 1))
    return (start, fit) if rms <= rms_limit and gain <= SETTLED_RTOL * cost else None


def polish_stage(
    problem: WindingProblem,
    result: PSOResult,
    bounds: SearchRange,
    *,
    polish: bool = True,
    max_iterations: int = 30,
) -> PolishedFit:
    """Stage 2: Levenberg-Marquardt from the swarm's best (``polish`` off: only the Jacobian)."""
    resistance, inductance = (float(v) for v in 10.0**result.x)
    k0 = problem.best_k(resistance, inductance, problem.inp.shift)
    theta = problem.theta0(resistance, inductance, k0)
    lower, upper = problem.limits(bounds.log_bounds())
    if polish:
        theta, resid, jac = levenberg_marquardt(
            problem.residual, theta, lower=lower, upper=upper, max_iterations=max_iterations,
            residual_and_jacobian=problem.residual_and_jacobian,
            # A fitted shift's or lag's column costs the moments of another shift: not on
            # trials that may be rejected.
            jacobian_on_trials=not (problem.fit_shift or problem.fit_lag),
        )  # fmt: skip
    else:
        resid = problem.residual(theta)
        jac = jacobian(problem.residual, theta)
    r, ell, k, shift = problem.unpack(theta)
    lag = problem.lag_of(theta)
    _, initial = problem.evaluate(r, ell, k, shift, lag)
    point = WindingPoint(r, ell, k, shift, float(initial[0]) if initial.size else 0.0, resid, lag)
    return PolishedFit(point, theta, jac)


def hold_or_smooth(
    smooth: WindingProblem,
    hold: WindingProblem,
    result: PSOResult,
    bounds: SearchRange,
    *,
    polish: bool = True,
) -> tuple[WindingProblem, PolishedFit]:
    """Stage 2 for a voltage without jumps: polish both ``smooth`` and ``hold``, keep the better.

    A drive that reports the voltage it holds for each period is described
    exactly by ``hold``; a voltage measured through a filter by ``smooth``.
    A voltage that shows a converter's jumps (:data:`CONVERTER_TRANSITIONS`) or
    its mains ripple (:data:`CONVERTER_RIPPLE`) is measured: ``smooth``.
    Otherwise the samples alone do not say which; the current does. A smooth
    fit whose shift is half a period early (:data:`HOLD_SHIFT`) is a hold in
    disguise: it beats hold only by averaging the voltage's noise (an
    errors-in-variables effect, not a better model). Otherwise ``smooth`` is
    kept when it explains the current decisively better
    (:data:`SMOOTH_OVER_HOLD` residual variances).
    """
    fit_smooth = polish_stage(smooth, result, bounds, polish=polish)
    sw = smooth.inp.switching
    if (sw is not None and sw.transition_share >= CONVERTER_TRANSITIONS) or (
        mains_ripple_share(smooth.voltage, smooth.dt) >= CONVERTER_RIPPLE
    ):
        # A converter's jumps or its ripple, seen through a filter: a measured voltage.
        # A drive's held reference has neither; a front-end delay can still make hold
        # fit well (and hold counts the voltage exact).
        return smooth, fit_smooth
    fit_hold = polish_stage(hold, result, bounds, polish=polish)
    if abs(fit_smooth.point.shift - HOLD_SHIFT) < HOLD_SHIFT_WIDTH:
        # The cubic read half a period early is a held value: the smooth model
        # imitates hold, and only beats it by smoothing the voltage's noise.
        return hold, fit_hold
    rss_smooth = float(fit_smooth.point.residual @ fit_smooth.point.residual)
    rss_hold = float(fit_hold.point.residual @ fit_hold.point.residual)
    sigma2 = rss_smooth / max(fit_smooth.point.residual.size, 1)
    # Noise on the measured voltage reaches eq. (1) through each model: the
    # held sample passes all of it, the band-limited reconstruction averages
    # neighbours and passes less. That share of smooth's lead is noise, not a
    # better model.
    noise_var = min(_input_noise(hold, fit_hold.point), _input_noise(smooth, fit_smooth.point))
    if noise_var > 0.0:
        rss_hold -= noise_var * (
            averaged_noise(hold, fit_hold.theta) - averaged_noise(smooth, fit_smooth.theta)
        )
    if sigma2 > 0 and (rss_hold - rss_smooth) / sigma2 > SMOOTH_OVER_HOLD:
        return smooth, fit_smooth
    return hold, fit_hold


def _input_noise(problem: WindingProblem, point: WindingPoint) -> float:
    """The white voltage-noise variance (V^2) the fit's residual shows (0: none)."""
    a_, c0, _, _ = ik.moment_coefficients(point.resistance_ohm, point.inductance_h, problem.dt)
    return input_noise_variance(point.residual, a_, c0)


#: Draws of white voltage noise that :func:`input_noise_std` propagates through the fit.
INPUT_NOISE_DRAWS = 8


@functools.lru_cache(maxsize=8)
def _noise_draws(n: int, count: int, seed: int) -> np.ndarray:
    """``count`` fixed draws of unit white noise over ``n`` samples from ``seed``, made once
    per window length (drawing them cost half of :func:`input_noise_std`); read-only."""
    out = np.random.default_rng(seed).standard_normal((count, n))
    out.flags.writeable = False
    return out


#: The band-limited moments of the noise draws, by window length, draws and shift
#: (:func:`_draw_moments`); at most :data:`DRAW_CACHE_SIZE` entries, oldest out first.
_draw_cache: dict[tuple[object, ...], list[np.ndarray]] = {}
DRAW_CACHE_SIZE = 8


def _draw_moments(
    problem: WindingProblem, theta: np.ndarray, count: int, seed: int
) -> list[np.ndarray]:
    """The moments of the fixed noise draws (:func:`_noise_draws`) through the problem's
    intersample model at ``theta`` (:meth:`WindingProblem.input_moments`).

    Held and averaged moments are the draws themselves, cheap. The band-limited ones
    cost a spectrum and three inverse transforms a draw (8 draws: 6 ms of a 10 kHz
    window) and depend only on the draws and the shift, once the draws are read as one
    segment over the whole window: white noise has nothing to carry across a gap between
    segments but its interpolant's tails, and the residual reads only the segments'
    intervals. Once a chain is decided its shift is held, so consecutive windows ask for
    the same moments; they are kept (read-only), and a hit returns the very arrays a miss
    computed (replay stays exact). Read per segment, a window split in two (a converter's
    dead time) missed every time and cost 15-35 ms. A ``switched`` voltage's short
    segments keep their own moments (their cubic is not the band-limited interpolant).
    """
    n = problem.voltage.shape[0]
    draws = _noise_draws(n, count, seed)
    inp = problem.inp
    if inp.model != "smooth":
        return [problem.input_moments(theta, d) for d in draws]
    shift = float(problem.unpack(theta)[3])
    key = (n, count, seed, shift)
    cached = _draw_cache.get(key)
    if cached is None:
        whole = Segments.whole(n)
        cached = [smooth_moments(d, whole, shift) for d in draws]
        for moments in cached:
            moments.flags.writeable = False
        while len(_draw_cache) >= DRAW_CACHE_SIZE:
            del _draw_cache[next(iter(_draw_cache))]
        _draw_cache[key] = cached
    return cached


def averaged_noise(problem: WindingProblem, theta: np.ndarray) -> float:
    """Expected share of eq. (1) (A^2 per V^2) that unit white noise on the voltage adds.

    The residual is affine in the voltage, so the noise's response is the
    residual's change when a draw of it is added, read through the problem's
    own intersample model (held, averaged or band-limited); averaged over
    :data:`NOISE_DRAWS` fixed draws.
    """
    columns = problem.moment_columns(theta, _draw_moments(problem, theta, NOISE_DRAWS, 0))
    return float(np.sum(columns * columns)) / NOISE_DRAWS


def input_noise_std(
    problem: WindingProblem, theta: np.ndarray, jac: np.ndarray, noise_var: float
) -> np.ndarray:
    """One-sigma move of each parameter of ``theta`` that white noise of variance ``noise_var``
    (V^2) on the measured voltage causes, to first order (``-(J'J)^-1 J' dr`` over draws).

    The sandwich bound reads the same noise from the fit's own residual, through a long-run
    covariance estimated from the window; where the voltage's noise, not the current's,
    fills the residual (a held voltage at 10 kHz: the noise's current wanders over La/Ra,
    57 samples), that estimate came out 2-3 times too small for ``L`` (a P-12 window: 0.37 %
    against 1.26 % over the draws, an error of -3.0 %), and the tracker read such windows as
    a change of La. The residual is affine in the voltage, so each draw costs one kernel
    pass through the problem's own intersample model.
    """
    try:
        inv = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.zeros(jac.shape[1])
    columns = problem.moment_columns(theta, _draw_moments(problem, theta, INPUT_NOISE_DRAWS, 1))
    moves = inv @ (jac.T @ columns)  # (parameters, draws)
    return math.sqrt(noise_var) * np.sqrt(np.mean(moves * moves, axis=1))


#: Half-widths (log10) of the stencils on which :func:`local_minimum` models the
#: compensated cost, one Newton step each: 5 %, then 0.5 % and 0.05 % for the last digits.
NEWTON_STENCILS = (0.02, 0.002, 0.0002)

#: The 3 x 3 stencil's offsets, ``log10 R`` major.
_STENCIL = np.array([(i, j) for i in (-1.0, 0.0, 1.0) for j in (-1.0, 0.0, 1.0)])


def local_minimum(cost: CostFunction, x0: np.ndarray, box: np.ndarray) -> np.ndarray | None:
    """The minimum of a smooth swarm cost over ``(log10 R, log10 L)`` near ``x0``, by Newton.

    Each step fits a quadratic to the cost on a 3 x 3 stencil (one call of the
    swarm's kernel, nine evaluations) and moves to its minimum; the stencils
    shrink (:data:`NEWTON_STENCILS`). None where the quadratic has no minimum
    (a curvature that is not positive) or a step leaves ``box``.
    """
    x = np.array(x0, dtype=np.float64)
    for h in NEWTON_STENCILS:
        c = np.asarray(cost(x + h * _STENCIL)).reshape(3, 3)
        grad = 0.5 * np.array([c[2, 1] - c[0, 1], c[1, 2] - c[1, 0]])
        cross = 0.25 * (c[2, 2] - c[2, 0] - c[0, 2] + c[0, 0])
        hess = np.array(
            [[c[2, 1] - 2.0 * c[1, 1] + c[0, 1], cross], [cross, c[1, 2] - 2.0 * c[1, 1] + c[1, 0]]]
        )
        if not (hess[0, 0] > 0.0 and np.linalg.det(hess) > 0.0):
            return None
        x = x - h * np.linalg.solve(hess, grad)
        if np.any(x <= box[:, 0]) or np.any(x >= box[:, 1]):
            return None
    return x


def search_and_polish(
    problem: WindingProblem,
    bounds: SearchRange,
    settings: SwarmSettings,
    rng: np.random.Generator,
    *,
    polish: bool = True,
    settled_rms: float | None = None,
    hold: Callable[[], WindingProblem] | None = None,
) -> tuple[WindingProblem, PSOResult, PolishedFit]:
    """Stages 1 and 2 as a window needs them: the problem kept, the swarm's result, the fit.

    A settled window (``settled_rms`` and a warm start ``settings.x0``) is
    polished from the warm start (:func:`settled_stage`), and searched by the
    swarm only if that fails. ``hold`` makes the held-voltage problem of a
    window whose intersample model is not decided: both are polished
    (:func:`hold_or_smooth`), never settled.
    """
    if settled_rms is not None and settings.x0 is not None and hold is None:
        settled = settled_stage(problem, bounds, settings.x0, settled_rms, polish=polish)
        if settled is not None:
            return problem, *settled
    result = swarm_stage(problem, bounds, settings, rng)
    if hold is not None:
        problem, fit = hold_or_smooth(problem, hold(), result, bounds, polish=polish)
    else:
        fit = polish_stage(problem, result, bounds, polish=polish)
    return problem, result, fit


def guard_stage(
    problem: WindingProblem,
    result: PSOResult,
    fit: PolishedFit,
    bounds: SearchRange,
    rebuild: Callable[[float], WindingProblem],
    *,
    polish: bool = True,
) -> tuple[WindingProblem, PolishedFit]:
    """Stage 2b: a switched fit whose delay asks for more of each segment left out, redone.

    ``rebuild(shift)`` makes the window's problem read at that relative delay
    (:meth:`~observer.estimation.problem.WindingProblem.guards`); it is
    polished from the fit's own point. Channels filtered alike (delay under a
    fifth of a sample) keep every sample: leaving the first of every segment
    out for a delay not yet known cost unfiltered 2 kHz recordings a sixth of
    their samples, and at 60 Hz mains Ra -0.7 % at 3 std.
    """
    if not problem.guards(fit.point.shift):
        return problem, fit
    guarded = rebuild(fit.point.shift)
    start = dataclasses.replace(
        result, x=np.log10([fit.point.resistance_ohm, fit.point.inductance_h])
    )
    return guarded, polish_stage(guarded, start, bounds, polish=polish)


def eiv_stage(
    problem: WindingProblem,
    plain: WindingPoint,
    bounds: SearchRange,
    settings: SwarmSettings,
    rng: np.random.Generator,
) -> EivCorrection:
    """Stage 3: remove the errors-in-variables bias of output error from the plain estimate.

    Noise on the measured voltage (and on ``if*omega``) makes eq. (1) favour a
    lower model gain, overestimating ``L``. The noise variance is read from the
    residual's autocorrelation
    (:func:`~observer.estimation.uncertainty.input_noise_variance`), its
    expected share of eq. (1) subtracted, and the minimum of what remains found
    in a narrow range around ``plain``: by Newton steps (:func:`local_minimum`,
    27 evaluations of the swarm's cost), or where they find none there, by the
    swarm re-run in that range (600 evaluations).
    """
    noise_var = _input_noise(problem, plain)
    if not noise_var > 0.0:
        return EivCorrection(plain, noise_var, np.zeros(3))
    shifted = (
        problem.with_shift(plain.shift, plain.lag)
        if (problem.fit_shift or problem.fit_lag)
        else problem
    )
    # The correction is a few percent: search only near the plain estimate. An
    # overestimated noise variance makes the compensated cost fall without
    # bound towards L -> 0 (gain 1/R), a spurious minimum the full range holds.
    local = bounds.around(
        plain.resistance_ohm, plain.inductance_h, COMPENSATION_FACTOR
    ).log_bounds()
    cost = shifted.swarm_cost(noise_var)
    start = np.log10([plain.resistance_ohm, plain.inductance_h])
    refined = local_minimum(cost, start, local)
    if refined is None:
        swarm = ParticleSwarm(
            cost, local, n_particles=max(20, settings.n_particles // 2), w=settings.w,
            schedule=settings.schedule, x0=start, rng=rng,
        )  # fmt: skip
        refined = swarm.run(max(30, settings.max_iterations)).x
    margin = np.minimum(refined - local[:, 0], local[:, 1] - refined)
    resistance, inductance = (float(v) for v in 10.0**refined)
    corrected = point_at(shifted, resistance, inductance, plain.shift)
    moved = np.abs(corrected.values() - plain.values())
    if np.all(margin > 0.01 * np.log10(COMPENSATION_FACTOR)):
        # The Cramer-Rao bound ignores input noise; the size of the correction
        # bounds how far input noise could have moved the estimate.
        return EivCorrection(corrected, noise_var, 0.5 * moved)
    # Pressed against the edge: the compensation model does not fit this
    # window (weak excitation, or unmodelled physics read as input noise).
    # Keep the plain fit. L may be off by as much as the box; R and K by as
    # much as the refused correction would have moved them.
    moved[1] = max(moved[1], (COMPENSATION_FACTOR - 1.0) * abs(plain.inductance_h))
    return EivCorrection(plain, 0.0, moved)


#: The specification test weights the residual by a low-pass at this fraction of
#: the sample rate: front ends (anti-aliasing filters sit near fs/4), aliasing
#: and the reconstruction between samples err at high frequencies.
SPEC_CUTOFF = 1.0 / 8.0


def butter2_lowpass(cutoff: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete 2nd-order Butterworth low-pass ``(b, a)``; ``cutoff`` per sample rate."""
    k = math.tan(math.pi * cutoff)
    q = math.sqrt(2.0)
    norm = 1.0 / (1.0 + q * k + k * k)
    b0 = k * k * norm
    b = np.array([b0, 2.0 * b0, b0])
    a = np.array([1.0, 2.0 * (k * k - 1.0) * norm, (1.0 - q * k + k * k) * norm])
    return b, a


@dataclass(frozen=True)
class SpecificationTest:
    """The low-frequency refit and the model error it reveals.

    Attributes
    ----------
    values : (3,) array
        ``R, L, K`` of the low-frequency fit.
    model_std : (3,) array
        One-sigma model error of ``R, L, K``: the part of the two fits'
        difference their noise does not explain (0 when it does).
    operating_point_std : (3,) array or None
        The part of ``model_std`` the fits over the low- and high-voltage halves found
        (:func:`operating_point_stage`); None: not tested.
    """

    values: np.ndarray
    model_std: np.ndarray
    operating_point_std: np.ndarray | None = None


def _weighted_refit(
    problem: WindingProblem,
    fit: PolishedFit,
    bounds: SearchRange,
    weigh: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit again with the residual weighted by the linear map ``weigh``: ``theta``, the
    weighted residual and Jacobian there.

    The weighting is linear: at the full fit the weighted residual and its Jacobian are the
    full fit's, weighted, and the refit moves theta by about the model error, too little to
    change the sensitivities: three steps with that Jacobian (the chord method, one residual
    each) land within a few percent of a std of the refit with fresh Jacobians (7 residuals,
    not 25).
    """
    start = (
        weigh(fit.point.residual),
        np.column_stack([weigh(np.ascontiguousarray(c)) for c in fit.jacobian.T]),
    )
    lower, upper = problem.limits(bounds.log_bounds())
    return levenberg_marquardt(
        lambda theta: weigh(problem.residual(theta)), fit.theta.copy(), lower=lower,
        upper=upper, max_iterations=3, start=start, fixed_jacobian=True,
    )  # fmt: skip


def specification_stage(
    problem: WindingProblem, fit: PolishedFit, bounds: SearchRange
) -> SpecificationTest:
    """Refit with the residual weighted to low frequencies; excess disagreement is model error.

    A Hausman test in effect: with a correct model both fits estimate the same
    parameters and differ by noise only, with variance about the difference
    of their variances; a model that errs at high frequencies (front ends,
    aliasing, the voltage between samples) pulls the full fit and not the
    low-frequency one. What the noise does not explain is reported as model
    error.
    """
    lengths = problem.segments.ends - problem.segments.starts + 1
    b, a = butter2_lowpass(SPEC_CUTOFF)

    def lowpass(x: np.ndarray) -> np.ndarray:
        out = np.empty_like(x)
        ik.lowpass_segments(x, lengths, b, a, out)
        return out

    theta_lp, resid_lp, jac_lp = _weighted_refit(problem, fit, bounds, lowpass)
    tau_samples = math.exp(fit.theta[1] - fit.theta[0]) / problem.dt
    std_full = crlb_std(fit.jacobian, fit.point.residual, tau_samples)
    std_lp = crlb_std(jac_lp, resid_lp, tau_samples + 1.0 / SPEC_CUTOFF)
    r_lp, l_lp, k_lp, _ = problem.unpack(theta_lp)
    values_lp = np.array([r_lp, l_lp, k_lp])
    full = fit.point.values()
    # theta holds ln R, ln L: compare those relatively, K absolutely.
    delta = np.array([math.log(r_lp / full[0]), math.log(l_lp / full[1]), k_lp - full[2]])
    noise_var = np.zeros(3)
    n_core = 2 + int(problem.fits_k)
    # An exact fit (a channel without noise) has no bound at all: inf on both sides, and no
    # model error can be read from the difference.
    with np.errstate(invalid="ignore"):
        gap = std_lp[:n_core] ** 2 - std_full[:n_core] ** 2
    noise_var[:n_core] = np.where(np.isnan(gap), np.inf, np.maximum(gap, 0.0))
    excess = np.maximum(delta**2 - noise_var, 0.0)
    model = np.sqrt(excess)
    model_std = np.array([full[0] * model[0], full[1] * model[1], model[2]])
    if not problem.fits_k:
        model_std[2] = 0.0
    return SpecificationTest(values_lp, model_std)


#: Blocks (s) a recording is cut into for :func:`operating_point_stage`; each goes to the half
#: of its mean |voltage|.
SPLIT_BLOCK_S = 0.5


def operating_point_stage(
    problem: WindingProblem, fit: PolishedFit, bounds: SearchRange, spec: SpecificationTest
) -> SpecificationTest:
    """``spec`` with the model error that depends on the operating point added to its
    ``model_std``: refit on the low- and on the high-voltage half of the samples.

    With a correct model both halves estimate the same parameters and differ by noise only;
    a reading whose error depends on the operating point does not. A chopper's pulses that
    fold onto zero frequency through the front end (a harmonic of the pulses on a multiple
    of the rate, a PWM sampled through an RC filter) read the voltage through a curve of the
    duty: its slope is a gain error that differs from one voltage to the next, and no noise
    bound covers it (the 440 V motor behind a chopper at 2.5 kHz sampled at 2 kHz: Ra -0.47 %
    at 13 std, K at 6 std; the halves' K differed by 5 of their stds). The halves' excess
    disagreement ``d`` is read as two draws of that error, whose one-sigma size ``|d| /
    sqrt(2)`` joins the estimate's model error. Over a whole recording only: a window spans
    too few operating points. Not for a voltage a line-commutated bridge made
    (:func:`~observer.estimation.linearity.made_by_a_bridge`): its jumps' fold is put back
    between the samples or bounded already, and what the halves' fits differ by there is how
    well that is done at each firing angle, which the full fit averages (the P-12's field
    behind an untold RC at 2 kHz, 8 s: Lf within 1 %, the halves' gap read as a std of 2.2 %).

    The halves are blocks of :data:`SPLIT_BLOCK_S` by their mean |voltage| (above or below the
    median); each refit weighs the residual by its half and takes three chord steps from the
    full fit, as :func:`specification_stage` does.
    """
    from observer.estimation.linearity import made_by_a_bridge

    if made_by_a_bridge(
        problem.voltage, problem.dt, winding="armature" if problem.emf is not None else "field"
    ):
        return spec
    seg = problem.segments
    if seg.starts.size == 0:
        return spec
    index = np.concatenate([np.arange(a, b + 1) for a, b in zip(seg.starts, seg.ends, strict=True)])
    if index.size != fit.point.residual.shape[0]:
        return spec
    size = np.abs(np.asarray(problem.voltage, dtype=np.float64))[index]
    per_block = max(1, int(round(SPLIT_BLOCK_S / problem.dt)))
    blocks = np.arange(index.size) // per_block
    if blocks[-1] < 3:
        return spec
    means = np.bincount(blocks, size) / np.bincount(blocks)
    high = means[blocks] > np.median(means)
    tau_samples = math.exp(fit.theta[1] - fit.theta[0]) / problem.dt
    halves = []
    for mask in (~high, high):
        if mask.sum() < 2 * per_block:
            return spec
        theta, resid, jac = _weighted_refit(
            problem, fit, bounds, functools.partial(np.multiply, mask.astype(np.float64))
        )
        halves.append((theta, crlb_std(jac[mask], resid[mask], tau_samples)))
    (theta_a, std_a), (theta_b, std_b) = halves
    k = 2 + int(problem.fits_k)
    # theta holds ln R, ln L (relative) and K (absolute), as the model error is reported.
    gap = (theta_a - theta_b)[:k]
    with np.errstate(invalid="ignore"):
        noise = (std_a**2 + std_b**2)[:k]
    excess = np.where(np.isfinite(noise), np.maximum(gap**2 - noise, 0.0), 0.0)
    model = np.zeros(3)
    model[:k] = np.sqrt(excess / 2.0)
    full = fit.point.values()
    model[:2] *= full[:2]
    return dataclasses.replace(
        spec, model_std=np.hypot(spec.model_std, model), operating_point_std=model
    )


def operating_point_part(
    spec: SpecificationTest | None, names: tuple[str, ...]
) -> dict[str, float]:
    """``{name: std}`` of :attr:`SpecificationTest.operating_point_std` for ``names`` (of
    ``R, L, K`` in order); empty where it was not tested."""
    if spec is None or spec.operating_point_std is None:
        return {}
    return {name: float(v) for name, v in zip(names, spec.operating_point_std, strict=False)}


def _combined(*terms: float) -> float:
    """Independent one-sigma terms in quadrature."""
    return float(np.linalg.norm(terms))


def _solve_tall(
    a: np.ndarray, b: np.ndarray, qr: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Least squares ``a x = b`` for a tall ``a`` (samples by a few parameters) and several
    right-hand sides: by ``a``'s QR and the small triangle's least squares (a rank-deficient
    ``a``, a parameter the window does not identify, is solved as ``lstsq`` would). LAPACK's
    least squares over the tall arrays took 2-10 ms for ten columns of 10^4 samples."""
    q, r = qr if qr is not None else np.linalg.qr(a)
    x: np.ndarray = np.linalg.lstsq(r, q.T @ b, rcond=None)[0]
    return x


#: Step (sample periods) of the voltage's delay for the residual's sensitivity to it.
SHIFT_STEP = 1e-2


def _nuisance_step(
    base: np.ndarray,
    column: np.ndarray,
    perpendicular: np.ndarray,
    move: np.ndarray,
    along: np.ndarray,
    residual: np.ndarray,
    tau_samples: float,
) -> tuple[float, np.ndarray, float]:
    """A nuisance ``column`` beside the fit's ``base``, measured in its ``residual``.

    The coefficient comes from the column's part the base cannot take up
    (``perpendicular``); with ``move`` and ``along`` (the base's least squares of the
    column and of the residual) it gives the joint Gauss-Newton step, the base's
    parameters then the coefficient; last, the coefficient's sandwich std. A column
    that leaves no trace: ``(nan, step, inf)``; an std that cannot be had: ``inf``.
    """
    cc = float(perpendicular @ perpendicular)
    coefficient = float(perpendicular @ residual) / cc if cc > 0.0 else math.nan
    step = np.append(along - move * coefficient, coefficient)
    if not math.isfinite(coefficient):
        return coefficient, step, math.inf
    augmented = np.column_stack([base, column])
    s = float(crlb_std(augmented, residual - augmented @ step, tau_samples)[-1])
    return coefficient, step, s if math.isfinite(s) else math.inf


def _untold_mismatch(
    problem: WindingProblem,
    fit: PolishedFit,
    columns: np.ndarray,
    tau_samples: float,
    k: int,
) -> UntoldMismatch:
    """What an untold mismatch of the channels' front ends leaves in ``R, L[, K]``: the
    whole one-sigma term, the part of it every window shares, and the commonest pair's
    size measured, with the delay that goes with it (what the daemon learns).

    ``columns`` are the residual's changes were the channels each pair of
    :data:`~observer.estimation.frontend.MISMATCH_SHAPES` (size 1), and, where
    the delay is held, per sample of delay. Each pair's size is a nuisance
    parameter a priori of standard deviation 1 (nobody told the front ends),
    and the window measures it where the mismatch leaves a trace the fitted
    ``R, L[, K]`` and delay cannot take up (its gain and phase differ across
    the ripple's harmonics and transients, where ``R + jwL`` cannot follow):
    a Gauss-Newton step with the column beside the Jacobian (and the delay's),
    its sandwich std, combined with the prior. The term is the largest move a
    measured size implies, counted :data:`~observer.estimation.frontend.MISMATCH_UNDERSEEN`
    times (it sees only part of a real pair's), with the commonest pair's
    posterior spread; that spread is the window's noise where the data
    measures the size, and the chain's (shared) where it cannot. A voltage
    corrected by a learned size (``problem.mismatch_applied``) adds
    :data:`~observer.estimation.frontend.MISMATCH_SHAPE` of the correction's
    move: the real pair need not have the commonest one's shape.
    """
    residual = fit.point.residual
    base = fit.jacobian
    shapes = columns
    shift = problem.unpack(fit.theta)[3]
    at_shift = 2 + int(problem.fits_k)
    if not problem.fit_shift:
        base = np.column_stack([base, columns[:, -1]])
        shapes = columns[:, :-1]
        at_shift = base.shape[1] - 1
    # One factorisation of the base for every column (a tall least squares per column
    # took a millisecond each): the columns' moves, and each one's size from its part
    # the base cannot take up.
    q, r_base = fit.qr if base is fit.jacobian else np.linalg.qr(base)
    along = _solve_tall(base, np.column_stack([shapes, residual]), (q, r_base))
    moves = np.abs(along[:k, :-1])
    perpendicular = shapes - q @ (q.T @ shapes)
    measured = MISMATCH_SHAPE * abs(problem.mismatch_applied) * moves[:, 0]
    spread = np.zeros(k)
    prior_share = 1.0
    learned = (problem.mismatch_applied, shift)
    for j in range(shapes.shape[1]):
        coefficient, step, s = _nuisance_step(
            base, shapes[:, j], perpendicular[:, j], along[:, j], along[:, -1], residual,
            tau_samples,
        )  # fmt: skip
        size = -coefficient
        if not (math.isfinite(size) and math.isfinite(s)):
            size, s = 0.0, math.inf
        var = 1.0 if math.isinf(s) else s * s / (1.0 + s * s)
        mean = size * (1.0 - var)
        measured = np.maximum(measured, MISMATCH_UNDERSEEN * abs(mean) * moves[:, j])
        if j == 0:
            spread = moves[:, 0] * math.sqrt(var)
            prior_share = var
            if math.isfinite(s):
                learned = (problem.mismatch_applied + size, shift - float(step[at_shift]))
    total = np.hypot(measured, spread)
    common = np.hypot(measured, spread * math.sqrt(prior_share))
    return UntoldMismatch(total, common, *learned)


@dataclass(frozen=True)
class UntoldMismatch:
    """What :func:`_untold_mismatch` found in a window."""

    total: np.ndarray
    """One-sigma moves of ``R, L[, K]`` (relative in ``R`` and ``L``)."""
    common: np.ndarray
    """The part of ``total`` every window shares."""
    size: float
    """The commonest pair's size the window measured, relative to the raw voltage."""
    shift: float
    """The voltage's delay (sample periods) that goes with that size."""


#: Fewer jumps than this in a window: their areas' common error is left to the alias bound
#: of the mean (:attr:`~observer.estimation.problem.WindingProblem.alias_v`).
JUMP_MIN = 12

#: Whether the measured error is corrected for (else it is carried in the std).
JUMP_CORRECTED = False

#: Jumps closer than this many samples apart on average: no jump stage. The window's
#: intervals are then mostly a jump's settling, whose misfit fills the column (a 6-pulse
#: bridge at 2 kHz, 6.7 samples a pulse, measured an area error up to twice the aliasing
#: factor in windows whose Ra was right, and doubled their std), and the ripple is sampled
#: too coarsely to inform Ra much: held-speed windows there had Ra's std at 2-9 %, covering
#: their error, without the stage.
JUMP_MIN_SPACING = 12.0


@dataclass(frozen=True)
class JumpAlias:
    """The common error of a window's jump areas (:func:`jump_stage`) and what it does.

    Attributes
    ----------
    size, std : float
        The error's posterior mean and standard deviation, as a share of each jump's size
        times a sample period (its prior: zero, with the front end's aliasing factor).
    delta : (3,) array
        The correction of ``ln R, ln L, K`` applied to the estimate: zero unless
        :data:`JUMP_CORRECTED`.
    spread, common : (3,) arrays
        The one-sigma move of ``ln R, ln L, K`` the std carries (the measured size's move and
        the posterior spread's; corrected, the spread's alone), and the part of the spread
        every window shares (where the data could not measure the size, the prior's).
    """

    size: float
    std: float
    delta: np.ndarray
    spread: np.ndarray
    common: np.ndarray


def _measured_column(
    problem: WindingProblem, fit: PolishedFit, moments: np.ndarray
) -> tuple[np.ndarray, float, float]:
    """A voltage error of the shape whose moments are ``moments``, as a nuisance column
    beside the fit's Jacobian (:func:`_nuisance_step`): the fitted parameters' move per unit
    of it, its measured coefficient and that coefficient's sandwich std."""
    theta = fit.theta
    column = problem.moment_columns(theta, [moments])[:, 0]
    base = fit.jacobian
    residual = fit.point.residual
    q, r = fit.qr
    move, along = _solve_tall(base, np.column_stack([column, residual]), (q, r)).T
    perpendicular = column - q @ (q.T @ column)
    tau_samples = math.exp(theta[1] - theta[0]) / problem.dt
    coefficient, _, s = _nuisance_step(
        base, column, perpendicular, move, along, residual, tau_samples
    )
    return move, coefficient, s


def jump_stage(problem: WindingProblem, fit: PolishedFit) -> JumpAlias | None:
    """Stage 3c: the error that the converter's jumps, seen through the front end and
    sampled, leave alike in every jump of the window: measured, and carried in the std.

    A jump of ``J`` volts at a place between samples reaches the samples of a
    filtered voltage with an error of its area, ``J*dt*g(theta)``
    (:func:`~observer.estimation.intersample.alias_factor`: one sigma of ``g`` is
    the aliasing factor). A bridge fires at the same point of its ripple every
    pulse and, on a steady drive, at places between samples that recur: the
    errors then add up, ripple-synchronous, into what the winding's
    ``R + sL`` reads as its resistance. Where the drive holds its speed (the
    only variation of the current is the ripple, a few microseconds of it
    are percents of ``Ra``), a 10 kHz P-12's windows read ``Ra`` -1.6 to
    -2.3 % at 3-4 std, the mean-voltage bound saw nothing, and the tracker
    raised a false ``Ra fell`` event. Here one area error ``beta*J*dt``
    common to every jump is a nuisance parameter, prior zero with the
    aliasing factor as its standard deviation, measured by a Gauss-Newton step
    with its column beside the Jacobian (its sandwich std). In those windows
    ``beta`` came out -0.012 +- 0.002 (the factor 0.014) and its move matched
    their error; in the held windows of another recording of the same drive
    it did not (moves of -2.0 % where Ra read +1.6 %): the column also takes
    up other misfit of the ripple. So the move of the measured size and its
    posterior spread is carried in the std, as a measured model error, and
    the estimate is left as it is (:data:`JUMP_CORRECTED`). ``None``: fewer
    than :data:`JUMP_MIN` jumps, jumps closer than :data:`JUMP_MIN_SPACING`,
    or no front end to alias through.
    """
    if problem.jumps is None or problem.jump_alias <= 0.0:
        return None
    jumps = problem.jumps[0].shape[0]
    if jumps < JUMP_MIN or problem.current.shape[0] < JUMP_MIN_SPACING * jumps:
        return None
    move, coefficient, s = _measured_column(problem, fit, problem.jump_moments())
    if not math.isfinite(coefficient):
        return None
    prior = problem.jump_alias
    shrink = 1.0 if math.isinf(s) else prior * prior / (prior * prior + s * s)
    posterior = prior if math.isinf(s) else prior * s / math.hypot(prior, s)
    k = 3 if problem.fits_k else 2
    delta = np.zeros(3)
    spread = np.zeros(3)
    common = np.zeros(3)
    size = 0.0 if math.isinf(s) else -coefficient * shrink
    if JUMP_CORRECTED:
        delta[:k] = -move[:k] * size
        spread[:k] = np.abs(move[:k]) * posterior
    else:
        spread[:k] = np.abs(move[:k]) * math.hypot(size, posterior)
    common[:k] = np.abs(move[:k]) * posterior * (posterior / prior)
    return JumpAlias(size, posterior, delta, spread, common)


@dataclass(frozen=True)
class OffsetFit:
    """The armature voltage reading's offset, measured in a window (:func:`offset_stage`), or
    the speed channel's delay (:func:`speed_delay`).

    Attributes
    ----------
    size, std : float
        Its posterior mean and standard deviation (V, or sample periods; its prior: zero,
        with :data:`OFFSET_SHARE` of the window's mean ``|va|``, or
        :data:`SPEED_DELAY_PRIOR`).
    spread, common : (3,) arrays
        The one-sigma move of ``ln R, ln L, K`` it leaves in the estimate (the posterior
        mean's and spread's), and the part of it every window shares (an offset is the same in
        every window; where the data could not measure it, the prior is).
    """

    size: float
    std: float
    spread: np.ndarray
    common: np.ndarray


def offset_stage(problem: WindingProblem, fit: PolishedFit) -> OffsetFit | None:
    """Stage 3d: the armature voltage reading's offset, a nuisance parameter measured.

    Every voltage sensor has an offset, and an armature current sensor's acts alike
    (``Ra`` times it): prior zero with :data:`OFFSET_SHARE` of the mean ``|va|`` as its
    standard deviation. A window whose current and speed vary tells ``R*ia``,
    ``K*if*omega`` and a constant apart, and measures it: a Gauss-Newton step with its
    column beside the Jacobian, with the column's sandwich std. The std carries its move as
    measured, with the posterior's spread, in place of the prior's (:func:`std_stage`):
    where the window measures it, far less than the prior; where a real offset is larger
    than the prior, more. The estimate keeps it: the column takes up other slow misfit too,
    and taken out (or with the sandwich bound's free nuisance dropped, as a prior on it
    would allow) the 440 V motor's K at 10 kHz was published ``ok`` 1.5-1.8 % off at 4-5
    std in windows of steady current and speed, and a brush drop behind a chopper no
    longer read as one. None: a held voltage (the drive's own reference), no ``K``
    fitted, or a voltage at zero.
    """
    if problem.inp.model == "hold" or not problem.fits_k:
        return None
    prior = OFFSET_SHARE * float(np.mean(np.abs(problem.voltage)))
    if not prior > 0.0:
        return None
    return _with_prior(problem, fit, problem.offset_moments(), prior)


def _with_prior(
    problem: WindingProblem, fit: PolishedFit, moments: np.ndarray, prior: float
) -> OffsetFit:
    """A nuisance voltage change of moments ``moments`` per unit, prior zero with standard
    deviation ``prior``, measured in the window (:func:`_measured_column`): its posterior
    and the moves of ``ln R, ln L, K`` it leaves."""
    move, coefficient, s = _measured_column(problem, fit, moments)
    moves = np.abs(move[:3])
    if not math.isfinite(coefficient) or math.isinf(s):
        return OffsetFit(0.0, prior, moves * prior, moves * prior)
    posterior = prior * s / math.hypot(prior, s)
    size = -coefficient * prior * prior / (prior * prior + s * s)
    spread = moves * math.hypot(size, posterior)
    common = moves * math.hypot(size, posterior * posterior / prior)
    return OffsetFit(size, posterior, spread, common)


def speed_delay(problem: WindingProblem, fit: PolishedFit) -> OffsetFit | None:
    """The EMF's timing against the current's, a nuisance parameter measured.

    Front ends untold, the speed may be sampled late (a multiplexed ADC, an encoder's
    speed taken over a period): prior zero with :data:`SPEED_DELAY_PRIOR` sample periods
    as its standard deviation. Read that late, the EMF errs by ``K*if*domega/dt`` times
    it. The window measures the misfit along that direction (as :func:`offset_stage`
    measures the offset) and the std carries its move as measured, with the posterior's
    spread; where the speed barely changes the move is small whatever the delay. What is
    measured is the misfit, not the channel's delay alone (the speed the EMF uses is
    reconstructed through the shaft's equation, :mod:`.mechanics`, which has its own
    timing): on the traction motor with the speed half a period late, 1 s windows read
    -0.76 to +0.27 periods, and -0.75 to +0.48 with none. The estimate keeps it, as it keeps
    the offset. None: front ends configured, a held or switched voltage, or no ``K``
    fitted.
    """
    if not (problem.untold_front_end and problem.emf is not None and problem.fits_k):
        return None
    # The EMF's change per sample of delay, as the voltage change it makes (the winding
    # sees v - K*emf).
    late = smooth_moments(problem.emf, problem.inp.segments, 1.0) - problem.mu_emf
    k_now = float(problem.unpack(fit.theta)[2])
    return _with_prior(problem, fit, -k_now * late, SPEED_DELAY_PRIOR)


def corrected_point(point: WindingPoint, jump: JumpAlias | None) -> WindingPoint:
    """``point`` with ``jump``'s correction of ``ln R, ln L, K`` applied."""
    if jump is None or not np.any(jump.delta):
        return point
    return dataclasses.replace(
        point,
        resistance_ohm=point.resistance_ohm * math.exp(float(jump.delta[0])),
        inductance_h=point.inductance_h * math.exp(float(jump.delta[1])),
        emf_constant_h=point.emf_constant_h + float(jump.delta[2]),
    )


def std_stage(
    problem: WindingProblem,
    fit: PolishedFit,
    eiv: EivCorrection,
    spec: SpecificationTest | None = None,
    jump: JumpAlias | None = None,
    offset_fit: OffsetFit | None = None,
) -> dict[str, float]:
    """Stage 4: one-sigma uncertainty of ``R, L[, K]`` (and the shift) of the final estimate.

    The sandwich bound at the polished optimum
    (:func:`~observer.estimation.uncertainty.crlb_std`, relative in ``R`` and
    ``L``), combined with the bound on the errors-in-variables bias and the
    model error of the specification test (:func:`specification_stage`).
    For the armature the bound treats an offset of a *measured* voltage (any
    model but ``hold``, which is the drive's own reference) as an unknown
    (:data:`OFFSET_SHARE`): every voltage sensor has one (a few tenths
    of a percent of its range), ``Ra*ia`` is a tenth or less of ``va``, and in a window whose
    current and speed are nearly steady an offset moves ``Ra`` and ``K``
    along the one direction the data cannot resolve (a 0.5 V offset on a
    550 V channel moves ``Ra`` by 1-1.5 %); the same direction carries the
    intersample and front-end errors that shift the window's optimum. Where the
    armature's ``offset_fit`` (:func:`offset_stage`) measured the offset, its move as
    measured replaces the prior's (the bound with the offset free stays).
    A measured voltage whose front ends are not configured adds the moves the
    commonest mismatch of the channels would cause
    (:func:`~observer.estimation.frontend.unknown_mismatch`): its gain at the
    ripple moves ``L`` whole, its phase in transients ``R`` and ``K``; on the
    armature also the EMF's timing as the window measures it (:func:`speed_delay`).

    For a measured voltage the result also holds ``shared_R``, ``shared_L``
    (and ``shared_K``): the part of the std that every window at the same
    operating point shares, a bias averaging windows does not shrink -- the
    sensor's offset, the alias of jumps locked to the samples (the
    ``steady`` term of the pieces whose jumps are locked), an untold
    mismatch of the channels' front ends, and the EMF's timing.
    """
    theta = fit.theta
    tau_samples = math.exp(theta[1] - theta[0]) / problem.dt
    jac = fit.jacobian
    measured = problem.inp.model != "hold"
    offset = np.zeros(3)
    mismatch = np.zeros(3)
    shared = np.zeros(3)
    untold: UntoldMismatch | None = None
    if measured:
        # The residual's change per error of the voltage (one solve for every column): the
        # sensor's offset, the alias of each piece, and the untold front ends' mismatch.
        pieces = problem.alias_pieces()
        changes = [problem.offset_moments()]
        changes += [problem.offset_moments(where) for where, _ in pieces]
        n_direct = len(changes)
        if problem.untold_front_end:
            # Channels whose front ends nobody told: were they one of the plausible pairs,
            # the voltage would differ by these (their gain at the ripple moves L whole) ...
            changes += problem.mismatch_moments(theta, MISMATCH_SHAPES)
            if not problem.fit_shift:
                # ... and, where the delay is held, the voltage read later (per sample).
                shift = problem.unpack(theta)[3]
                lag = problem.lag_of(theta)
                changes.append(
                    (problem.mu(shift + SHIFT_STEP, lag) - problem.mu(shift, lag)) / SHIFT_STEP
                )
        columns = problem.moment_columns(theta, changes)
        column = columns[:, 0]
        if problem.fits_k:
            # The unknown offset as a free nuisance parameter: a window whose
            # current and speed barely vary cannot tell R*ia from K*if*omega.
            jac = np.column_stack([jac, column])
        # And the bias a constant voltage error of a plausible size leaves where
        # it can be told apart (the estimate does not fit it): the sensor's
        # offset, and the error of the samples' mean that jumps seen through
        # the front end leave (aliasing; locked to the samples on a steady
        # bridge, so it does not average out over the window).
        k = 3 if problem.fits_k else 2
        # The parameters' moves per volt of each error (one solve for every column).
        per_volt = np.abs(_solve_tall(fit.jacobian, columns[:, :n_direct], fit.qr)[:k])
        if offset_fit is not None:
            # Measured (offset_stage): what its posterior leaves.
            offset[:k] = offset_fit.spread[:k]
            shared[:k] = offset_fit.common[:k]
        else:
            offset[:k] = per_volt[:, 0] * OFFSET_SHARE * float(np.mean(np.abs(problem.voltage)))
            shared[:k] = offset[:k]
        if pieces:
            # The same error over the whole window (a steady bridge) or one per piece
            # (the firing angle moves): whichever moves the parameter more.
            steady = per_volt[:, 0] * float(np.sqrt(np.mean(np.square(problem.alias_v))))
            volts = np.array([v for _, v in pieces])
            each = np.sqrt(np.sum((per_volt[:, 1 : 1 + len(pieces)] * volts) ** 2, axis=1))
            offset[:k] = np.hypot(offset[:k], np.maximum(steady, each))
            pairs = zip(problem.alias_v, problem.alias_locked, strict=True)
            locked_v = [v if lock else 0.0 for v, lock in pairs]
            shared_alias = per_volt[:, 0] * float(np.sqrt(np.mean(np.square(locked_v))))
            shared[:k] = np.hypot(shared[:k], shared_alias)
        if problem.untold_front_end:
            untold = _untold_mismatch(problem, fit, columns[:, n_direct:], tau_samples, k)
            mismatch[:k] = untold.total
            # A mismatch of the channels is the chain's, the same in every window.
            shared[:k] = np.hypot(shared[:k], untold.common)
        speed = speed_delay(problem, fit)
        if speed is not None:
            offset[:k] = np.hypot(offset[:k], speed.spread[:k])
            # The chain's own delay: the same in every window.
            shared[:k] = np.hypot(shared[:k], speed.common[:k])
        if jump is not None:
            # The jumps' common area error: its measured move and its spread.
            offset[:k] = np.hypot(offset[:k], jump.spread[:k])
            shared[:k] = np.hypot(shared[:k], jump.common[:k])
        offset[:2] *= (eiv.point.resistance_ohm, eiv.point.inductance_h)
        shared[:2] *= (eiv.point.resistance_ohm, eiv.point.inductance_h)
        mismatch[:2] *= (eiv.point.resistance_ohm, eiv.point.inductance_h)
    std = crlb_std(jac, fit.point.residual, tau_samples)
    if eiv.input_noise_var > 0.0:
        # The voltage's noise, carried through the fit (the sandwich under-reads it).
        std = np.maximum(std, input_noise_std(problem, theta, jac, eiv.input_noise_var))
    point = eiv.point
    model = spec.model_std if spec is not None else np.zeros(3)
    floor = MODEL_FLOOR if measured else {"R": 0.0, "L": 0.0, "K": 0.0}
    out = {
        "R": _combined(
            point.resistance_ohm * std[0], eiv.bias_bound[0], model[0], offset[0],
            floor["R"] * point.resistance_ohm, mismatch[0],
        ),
        "L": _combined(
            point.inductance_h * std[1], eiv.bias_bound[1], model[1], offset[1],
            floor["L"] * point.inductance_h, mismatch[1],
        ),
    }  # fmt: skip
    i = 2
    if problem.emf is not None:
        out["K"] = (
            _combined(
                std[i],
                eiv.bias_bound[2],
                model[2],
                offset[2],
                floor["K"] * abs(point.emf_constant_h),
                mismatch[2],
            )  # fmt: skip
            if problem.fits_k
            else 0.0
        )
        i += int(problem.fits_k)
    if problem.untold_front_end:
        out["front_end_L"] = float(mismatch[1])
        if untold is not None:
            out["mismatch_size"] = untold.size
            out["mismatch_shift"] = untold.shift
    if measured:
        for j, name in enumerate(("R", "L", "K")[: 2 + int(problem.fits_k)]):
            out[f"shared_{name}"] = float(shared[j])
    if problem.fit_shift:
        out["shift"] = float(std[i])
        i += 1
    if problem.fit_lag:
        out["lag"] = float(std[i])
    return out
