"""Output-error estimation of winding parameters with the paper's PSO.

Field and armature are estimated separately, as in the paper:

* field: ``(Rf, Lf)`` from ``vf`` and ``if``;
* armature: ``(Ra, La, K)`` from ``va``, ``ia`` and the measured ``if`` and ``omega``.

The target is the paper's eq. (1), the sum of squared differences between the
measured and the simulated winding current. The swarm searches the nonlinear
parameters ``(R, L)`` on a logarithmic scale (ranges derived from the data span
decades); the parameters the simulated current is linear in (``K`` and the
initial current) are solved in closed form for every particle. The swarm's best
is then polished by Levenberg-Marquardt on all parameters, which lands on the
exact minimum so the Cramer-Rao bound describes the estimate's spread, and the
uncertainty is read from the Fisher information there.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from observer.estimation import kernels
from observer.estimation.pso import ParticleSwarm, PSOResult

log = logging.getLogger(__name__)

CIRCUITS = ("field", "armature")

#: The errors-in-variables refinement searches within this factor of the plain estimate.
_COMPENSATION_FACTOR = 1.5


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


@dataclass(frozen=True)
class CircuitEstimate:
    """Estimated parameters of one winding.

    Attributes
    ----------
    circuit : {"field", "armature"}
    resistance_ohm, inductance_h : float
    emf_constant_h : float or None
        ``K`` of ``K*if*omega`` (armature only; V*s/(rad*A)).
    initial_current_a : float
        Fitted current at the window's first sample.
    rms_a : float
        Root-mean-square current error of the fit (A).
    std : dict
        One-sigma uncertainty per parameter (``R``, ``L``, ``K``): the Cramer-Rao
        bound from the Fisher information at the optimum with the fit's residual
        variance; for the armature combined with the size of the errors-in-variables
        correction (the bound alone ignores noise on the measured voltages).
    n_samples : int
    search_range : SearchRange
    pso : PSOResult
        The swarm search (its ``x`` is ``log10 (R, L)``).
    polished : bool
        Whether Levenberg-Marquardt refined the swarm's best.
    input_noise_var : float
        Variance (V^2) of white noise on the model's input voltage found in the
        residual and compensated (0: none found, or compensation off).
    """

    circuit: str
    resistance_ohm: float
    inductance_h: float
    emf_constant_h: float | None
    initial_current_a: float
    rms_a: float
    std: Mapping[str, float]
    n_samples: int
    search_range: SearchRange
    pso: PSOResult = field(repr=False)
    polished: bool = True
    input_noise_var: float = 0.0

    @property
    def time_constant_s(self) -> float:
        return self.inductance_h / self.resistance_ohm

    def relative_std(self, name: str) -> float:
        """``std[name] / |value|``: e.g. > 0.05 means the window hardly identifies it."""
        value = {"R": self.resistance_ohm, "L": self.inductance_h, "K": self.emf_constant_h}[name]
        if value is None or value == 0:
            return math.inf
        return self.std[name] / abs(value)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary: ``R, L, (K), rms, std, rel_std, ...``."""
        out: dict[str, Any] = {"R": self.resistance_ohm, "L": self.inductance_h}
        if self.emf_constant_h is not None:
            out["K"] = self.emf_constant_h
        out["tau"] = self.time_constant_s
        out["rms"] = self.rms_a
        out["std"] = dict(self.std)
        out["rel_std"] = {name: self.relative_std(name) for name in self.std}
        out["i0"] = self.initial_current_a
        out["n_samples"] = self.n_samples
        out["input_noise_var"] = self.input_noise_var
        out["iterations"] = self.pso.n_iterations
        out["evaluations"] = self.pso.n_evaluations
        out["search_range"] = {
            "R": list(self.search_range.resistance_ohm),
            "L": list(self.search_range.inductance_h),
        }
        return out


# ----------------------------------------------------------------- search range


def _kernel_array(x: Any) -> np.ndarray:
    """Contiguous, writable float64: the one array type the kernels are compiled for.

    numba compiles a separate specialisation for read-only arrays (a Recording's
    are), which on a cold cache costs seconds at the first real window.
    """
    return np.require(x, dtype=np.float64, requirements=["C", "W"])


def _check_signals(**signals: np.ndarray) -> int:
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


def field_search_range(vf: np.ndarray, i_f: np.ndarray, dt: float) -> SearchRange:
    """A wide search range for ``(Rf, Lf)`` derived from the data alone.

    The resistance is centred on the static least-squares ratio ``vf/if`` and
    spans a factor 4 either way; the time constant spans from a tenth of a
    sample period to twice the record length.
    """
    n = _check_signals(vf=vf, i_f=i_f)
    power = float(np.dot(i_f, i_f))
    if power <= 0 or np.sqrt(power / n) < 1e-9:
        raise EstimationError("the field current is zero: the field circuit is not excited")
    r0 = float(np.dot(vf, i_f)) / power
    if not r0 > 0:
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
    n = _check_signals(va=va, ia=ia, i_f=i_f, omega=omega)
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


# --------------------------------------------------------------- linear parts


def _field_linear(
    resistance: float, inductance: float, vf: np.ndarray, i_f: np.ndarray, dt: float
) -> tuple[float, np.ndarray]:
    """Best initial current and the residual for given ``(R, L)``."""
    forced = kernels.simulate_rl(resistance, inductance, 0.0, vf, dt)
    free = kernels.simulate_rl(resistance, inductance, 1.0, np.zeros_like(vf), dt)
    d = i_f - forced
    i0 = float(d @ free) / float(free @ free)
    return i0, d - i0 * free


def _armature_linear(
    resistance: float,
    inductance: float,
    va: np.ndarray,
    emf: np.ndarray,
    ia: np.ndarray,
    dt: float,
    emf_constant: float | None,
) -> tuple[float, float, np.ndarray]:
    """Best ``(K, i0)`` (``K`` held if given) and the residual for given ``(R, L)``."""
    zeros = np.zeros_like(va)
    free = kernels.simulate_rl(resistance, inductance, 1.0, zeros, dt)
    if emf_constant is not None:
        forced = kernels.simulate_armature(resistance, inductance, emf_constant, 0.0, va, emf, dt)
        d = ia - forced
        i0 = float(d @ free) / float(free @ free)
        return emf_constant, i0, d - i0 * free
    forced = kernels.simulate_rl(resistance, inductance, 0.0, va, dt)
    forced_emf = kernels.simulate_rl(resistance, inductance, 0.0, emf, dt)
    basis = np.column_stack([-forced_emf, free])
    coef, *_ = np.linalg.lstsq(basis, ia - forced, rcond=None)
    return float(coef[0]), float(coef[1]), ia - forced - basis @ coef


# ------------------------------------------------------ polish and uncertainty


def _jacobian(residual: Any, theta: np.ndarray) -> np.ndarray:
    """Sensitivities of ``residual`` at ``theta`` by central differences.

    The models are cheap (microseconds per simulation) and smooth in every parameter.
    """
    cols = []
    for j in range(theta.size):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        cols.append((residual(up) - residual(down)) / (2 * h))
    return np.column_stack(cols)


def _levenberg_marquardt(
    residual: Any,
    theta: np.ndarray,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    max_iterations: int = 30,
    rtol: float = 1e-8,
    step_tol: float = 1e-9,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimise ``|residual(theta)|^2``; return ``theta``, residual and Jacobian there.

    Sensitivities come from :func:`_jacobian`. Steps
    are kept inside ``[lower, upper]`` (the swarm's search range): in a window
    that does not identify a parameter the cost is flat along it, and an
    unbounded step would run ``log L`` to overflow.
    """
    lo = np.full(theta.size, -np.inf) if lower is None else lower
    hi = np.full(theta.size, np.inf) if upper is None else upper

    def safe_residual(th: np.ndarray) -> np.ndarray | None:
        try:
            with np.errstate(all="ignore"):
                r_ = residual(th)
        except (OverflowError, ZeroDivisionError, FloatingPointError):
            return None
        return r_ if np.all(np.isfinite(r_)) else None

    r = residual(theta)
    cost = float(r @ r)
    jac = _jacobian(residual, theta)
    damping = 1e-3
    for _ in range(max_iterations):
        jtj = jac.T @ jac
        grad = jac.T @ r
        scale = np.sqrt(np.maximum(np.diag(jtj), 1e-300))
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
            r_safe = safe_residual(trial)
            if r_safe is None:
                damping *= 10
                continue
            r_trial = r_safe
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
        jac = _jacobian(residual, theta)
        damping = max(damping / 10, 1e-9)
        # Converged, or creeping along a direction the window does not identify
        # (flat cost, e.g. Lf under constant field voltage): more steps buy nothing.
        if relative_gain < rtol or moved < step_tol:
            break
    return theta, r, jac


def _log_limits(bounds: SearchRange, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Limits of ``(ln R, ln L, <free linear parameters>)`` from a search range."""
    lower = np.full(size, -np.inf)
    upper = np.full(size, np.inf)
    lower[:2] = np.log([bounds.resistance_ohm[0], bounds.inductance_h[0]])
    upper[:2] = np.log([bounds.resistance_ohm[1], bounds.inductance_h[1]])
    return lower, upper


def _crlb_std(
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
    try:
        bread = np.linalg.inv(jac.T @ jac)
    except np.linalg.LinAlgError:
        return np.full(p, np.inf)
    sigma2 = float(residual @ residual) / max(n - p, 1)
    white = sigma2 * np.diag(bread)
    max_lag = int(min(3.0 * time_constant_samples, 400, n // 4))
    if max_lag >= 1:
        # Bartlett-weighted long-run covariance as overlapping batch means: the
        # covariance of the scores' sums over every run of max_lag + 1 samples
        # (one cumulative sum and one product instead of one product per lag).
        scores = jac * residual[:, None]
        cum = np.vstack([np.zeros((1, p)), np.cumsum(scores, axis=0)])
        batch = max_lag + 1
        sums = cum[batch:] - cum[:-batch]
        meat = (sums.T @ sums) / batch * (n / sums.shape[0])
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
    cov = np.array([r[:-lag] @ r[lag:] / n for lag in range(1, m + 1)])
    shape = b * b * a ** np.arange(1, m + 1) / (1.0 - a * a)
    # A constant term takes up slow structure (model error, drift) that would
    # otherwise be read as input noise and over-correct.
    design = np.column_stack([shape, np.ones(m)])
    (s, _slow), *_ = np.linalg.lstsq(design, cov, rcond=None)
    return max(float(s), 0.0)


# ------------------------------------------------------------------ estimators


def _run_swarm(
    cost: Any,
    search_range: SearchRange,
    *,
    n_particles: int,
    max_iterations: int,
    schedule: str | tuple[float, float],
    w: float,
    rng: int | np.random.Generator | None,
    x0: tuple[float, float] | None,
    init_range: SearchRange | None,
    explore_fraction: float,
    tol: float,
) -> PSOResult:
    def search(generator: np.random.Generator) -> PSOResult:
        swarm = ParticleSwarm(
            cost,
            box,
            n_particles=n_particles,
            w=w,
            schedule=schedule,
            x0=None if x0 is None else np.log10(np.asarray(x0, dtype=np.float64)),
            init_bounds=None if init_range is None else init_range.log_bounds(),
            explore_fraction=explore_fraction,
            tol=tol,
            rng=generator,
        )
        return swarm.run(max_iterations)

    box = search_range.log_bounds()
    generator = np.random.default_rng(rng)
    result = search(generator)
    # A best on a wall of the box is usually a swarm that settled on a flat
    # region (e.g. a time constant far below one sample, where the cost no
    # longer depends on L): search once more with fresh draws, keep the better.
    wall = 0.005 * (box[:, 1] - box[:, 0])
    if np.any((result.x - box[:, 0] < wall) | (box[:, 1] - result.x < wall)):
        retry = search(np.random.default_rng(generator.integers(2**63)))
        if retry.cost < result.cost:
            log.debug("swarm best on the search wall; the restart found a lower cost")
            result = retry
    return result


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
    vf = _kernel_array(vf)
    i_f = _kernel_array(i_f)
    n = _check_signals(vf=vf, i_f=i_f)
    rng_ = np.random.default_rng(rng)
    bounds = search_range if search_range is not None else field_search_range(vf, i_f, dt)

    def cost(x: np.ndarray) -> np.ndarray:
        return kernels.rl_swarm_costs(x, vf, i_f, dt, True, 0.0)

    result = _run_swarm(
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
    lower, upper = _log_limits(bounds, theta.size)
    if polish:
        theta, resid, jac = _levenberg_marquardt(residual, theta, lower=lower, upper=upper)
    else:
        resid = residual(theta)
        jac = _jacobian(residual, theta)
    std_log = _crlb_std(jac, resid, math.exp(theta[1] - theta[0]) / dt)
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
    va = _kernel_array(va)
    ia = _kernel_array(ia)
    i_f = _kernel_array(i_f)
    omega = _kernel_array(omega)
    n = _check_signals(va=va, ia=ia, i_f=i_f, omega=omega)
    rng_ = np.random.default_rng(rng)
    bounds = (
        search_range if search_range is not None else armature_search_range(va, ia, i_f, omega, dt)
    )
    emf = kernels.emf_input(i_f, omega)
    k_arg = math.nan if emf_constant is None else float(emf_constant)

    def cost(x: np.ndarray) -> np.ndarray:
        return kernels.armature_swarm_costs(x, va, emf, ia, dt, True, k_arg, 0.0)

    result = _run_swarm(
        cost, bounds, n_particles=n_particles, max_iterations=max_iterations,
        schedule=schedule, w=w, rng=rng_, x0=x0, init_range=init_range,
        explore_fraction=explore_fraction, tol=tol,
    )  # fmt: skip
    resistance, inductance = (float(v) for v in 10.0**result.x)
    k_value, i0, resid = _armature_linear(resistance, inductance, va, emf, ia, dt, emf_constant)

    fit_k = emf_constant is None

    def residual(theta: np.ndarray) -> np.ndarray:
        r_, l_ = math.exp(theta[0]), math.exp(theta[1])
        k_ = theta[3] if fit_k else k_value
        return ia - kernels.simulate_armature(r_, l_, k_, theta[2], va, emf, dt)

    theta = np.array(
        [math.log(resistance), math.log(inductance), i0] + ([k_value] if fit_k else [])
    )
    lower, upper = _log_limits(bounds, theta.size)
    if polish:
        theta, resid, jac = _levenberg_marquardt(residual, theta, lower=lower, upper=upper)
    else:
        resid = residual(theta)
        jac = _jacobian(residual, theta)
    std = _crlb_std(jac, resid, math.exp(theta[1] - theta[0]) / dt)
    resistance, inductance, i0 = math.exp(theta[0]), math.exp(theta[1]), float(theta[2])
    if fit_k:
        k_value = float(theta[3])
    noise_var = 0.0
    plain = np.array([resistance, inductance, k_value])
    bias_bound = np.zeros(3)
    if compensate_input_noise:
        a_, b_ = kernels.zoh_coefficients(resistance, inductance, dt)
        noise_var = input_noise_variance(resid, a_, b_)
    if noise_var > 0.0:

        def compensated(x: np.ndarray) -> np.ndarray:
            return kernels.armature_swarm_costs(x, va, emf, ia, dt, True, k_arg, noise_var)

        # The correction is a few percent: search only near the plain estimate. An
        # overestimated noise variance makes the compensated cost fall without
        # bound towards La -> 0 (gain 1/R), a spurious minimum the full range holds.
        local = bounds.around(resistance, inductance, _COMPENSATION_FACTOR).log_bounds()
        swarm = ParticleSwarm(
            compensated, local, n_particles=max(20, n_particles // 2), w=w,
            schedule=schedule, x0=np.log10([resistance, inductance]), rng=rng_,
        )  # fmt: skip
        refined = swarm.run(max(30, max_iterations))
        margin = np.minimum(refined.x - local[:, 0], local[:, 1] - refined.x)
        if np.all(margin > 0.01 * np.log10(_COMPENSATION_FACTOR)):
            resistance, inductance = (float(v) for v in 10.0**refined.x)
            k_value, i0, resid = _armature_linear(
                resistance, inductance, va, emf, ia, dt, emf_constant
            )
            # The Cramer-Rao bound ignores input noise; the size of the correction
            # bounds how far input noise could have moved the estimate.
            bias_bound = 0.5 * np.abs(np.array([resistance, inductance, k_value]) - plain)
        else:
            # Pressed against the edge: the compensation model does not fit this
            # window (weak excitation, or unmodelled physics read as input noise).
            # Keep the plain fit. La may be off by as much as the box; R and K by
            # as much as the refused correction would have moved them (usually
            # little: it is La that input noise biases).
            noise_var = 0.0
            r_edge, l_edge = (float(v) for v in 10.0**refined.x)
            k_edge, _, _ = _armature_linear(r_edge, l_edge, va, emf, ia, dt, emf_constant)
            bias_bound = np.abs(np.array([r_edge, l_edge, k_edge]) - plain)
            bias_bound[1] = max(bias_bound[1], (_COMPENSATION_FACTOR - 1.0) * abs(plain[1]))
    stds_ = np.hypot(
        np.array([resistance * std[0], inductance * std[1], std[3] if fit_k else 0.0]), bias_bound
    )
    stds = {"R": float(stds_[0]), "L": float(stds_[1]), "K": float(stds_[2]) if fit_k else 0.0}
    return CircuitEstimate(
        circuit="armature",
        resistance_ohm=resistance,
        inductance_h=inductance,
        emf_constant_h=k_value,
        initial_current_a=i0,
        rms_a=float(np.sqrt(np.mean(resid * resid))),
        std=stds,
        n_samples=n,
        search_range=bounds,
        pso=result,
        polished=polish,
        input_noise_var=noise_var,
    )


# ------------------------------------------------------------------ recordings

#: Channels each circuit needs.
CIRCUIT_CHANNELS = {"field": ("vf", "if"), "armature": ("va", "ia", "if", "omega")}


def _configured_range(cfg: Any) -> SearchRange | None:
    """A SearchRange from a config section with optional ``R`` and ``L``, or None."""
    if cfg is None or (cfg.R is None and cfg.L is None):
        return None
    if cfg.R is None or cfg.L is None:
        raise EstimationError("a configured search range needs both R and L")
    return SearchRange(tuple(cfg.R), tuple(cfg.L))


def estimate_recording(
    rec: Any, circuits: tuple[str, ...] = CIRCUITS, settings: Any = None, *, path: str | None = None
) -> dict[str, CircuitEstimate]:
    """Estimate the requested circuits of a :class:`~observer.recording.Recording`.

    Parameters
    ----------
    rec : Recording
    circuits : tuple of {"field", "armature"}
    settings : observer.config.EstimateConfig, optional
        Swarm settings and optional search ranges; defaults apply when omitted.
    path : str, optional
        File name used in error messages.
    """
    from observer.config import EstimateConfig

    cfg = settings if settings is not None else EstimateConfig()
    out: dict[str, CircuitEstimate] = {}
    common = dict(
        n_particles=cfg.particles,
        max_iterations=cfg.iterations,
        schedule=cfg.schedule,
        w=cfg.inertia,
        polish=cfg.polish,
    )
    for circuit in circuits:
        if circuit not in CIRCUIT_CHANNELS:
            raise EstimationError(f"unknown circuit {circuit!r}; expected one of {CIRCUITS}")
        rec.require(*CIRCUIT_CHANNELS[circuit], path=path, purpose=f"the {circuit} circuit")
        # One seed per circuit, so estimating one circuit alone gives the same numbers.
        rng = np.random.default_rng([cfg.seed, CIRCUITS.index(circuit)])
        prefix = f"{path}: " if path else ""
        try:
            if circuit == "field":
                out[circuit] = estimate_field(
                    rec["vf"], rec["if"], rec.dt, rng=rng,
                    search_range=_configured_range(cfg.field), **common,  # type: ignore[arg-type]
                )  # fmt: skip
            else:
                out[circuit] = estimate_armature(
                    rec["va"], rec["ia"], rec["if"], rec["omega"], rec.dt, rng=rng,
                    search_range=_configured_range(cfg.armature), **common,  # type: ignore[arg-type]
                )  # fmt: skip
        except EstimationError as exc:
            raise EstimationError(f"{prefix}{circuit} circuit: {exc}") from None
    return out
