"""Particle-swarm optimisation as in the paper's eq. (2).

``V <- w*V + c1*r1*(pb - X) + c2*r2*(gb - X)``, ``X <- X + V`` with inertia
``w`` (0.7 in the paper), individual weight ``c1`` and social weight ``c2``.
The paper names four coefficient schedules, all available here:

``social``       c1 = 0.1, c2 = 1.5 throughout
``individual``   c1 = 1.5, c2 = 0.1 throughout
``s-k``          from social to individual, 0.01 per iteration (the paper's best)
``k-s``          from individual to social, 0.01 per iteration

The API follows :func:`scipy.optimize.differential_evolution`: a function for the
common case (:func:`minimize`) and a stepping solver (:class:`ParticleSwarm`) for
the observer, which runs one window's search while it keeps acquiring.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from observer.estimation import kernels

CostFunction = Callable[[np.ndarray], np.ndarray]
"""A swarm cost: ``(n_particles, n_params) -> (n_particles,)``."""

SOCIAL = (0.1, 1.5)
INDIVIDUAL = (1.5, 0.1)
SCHEDULE_STEP = 0.01
SCHEDULES = ("social", "individual", "s-k", "k-s")


def coefficients(schedule: str | tuple[float, float], iteration: int) -> tuple[float, float]:
    """Return ``(c1, c2)`` of ``schedule`` at ``iteration`` (0-based).

    Parameters
    ----------
    schedule : {"social", "individual", "s-k", "k-s"} or (c1, c2)
        A named schedule from the paper, or constant weights.
    iteration : int
        Iteration number, from 0.
    """
    if not isinstance(schedule, str):
        c1, c2 = schedule
        return float(c1), float(c2)
    return _named_coefficients(schedule, int(iteration))


@functools.lru_cache(maxsize=4096)
def _named_coefficients(schedule: str, iteration: int) -> tuple[float, float]:
    """:func:`coefficients` of a named schedule, remembered: every swarm step asks for them."""
    if schedule == "social":
        return SOCIAL
    if schedule == "individual":
        return INDIVIDUAL
    # Smooth transition: each weight moves 0.01 per iteration until it reaches
    # the other behaviour's value, then stays there.
    moved = SCHEDULE_STEP * iteration
    if schedule == "s-k":
        start, end = SOCIAL, INDIVIDUAL
    elif schedule == "k-s":
        start, end = INDIVIDUAL, SOCIAL
    else:
        raise ValueError(f"unknown schedule {schedule!r}; expected one of {SCHEDULES} or (c1, c2)")
    c1 = start[0] + np.sign(end[0] - start[0]) * min(moved, abs(end[0] - start[0]))
    c2 = start[1] + np.sign(end[1] - start[1]) * min(moved, abs(end[1] - start[1]))
    return round(float(c1), 12), round(float(c2), 12)


@dataclass(frozen=True)
class PSOResult:
    """Outcome of a swarm search.

    Attributes
    ----------
    x : ndarray
        Best position found (in the optimiser's coordinates).
    cost : float
        Cost at ``x``.
    n_iterations : int
        Iterations run.
    n_evaluations : int
        Cost evaluations (particles x iterations, plus the initial swarm).
    history : ndarray
        Best cost after initialisation and after every iteration.
    converged : bool
        True if the relative-improvement tolerance stopped the search.
    message : str
        Why the search stopped.
    """

    x: np.ndarray
    cost: float
    n_iterations: int
    n_evaluations: int
    history: np.ndarray = field(repr=False)
    converged: bool
    message: str


class ParticleSwarm:
    """Stepping particle-swarm solver.

    Parameters
    ----------
    cost : callable
        Swarm cost ``(n_particles, n_params) -> (n_particles,)``.
    bounds : sequence of (low, high)
        The feasible box; particles never leave it.
    n_particles : int, default 100
    w : float, default 0.7
        Inertia weight.
    schedule : str or (c1, c2), default "s-k"
        Coefficient schedule, see :func:`coefficients`.
    x0 : array_like, optional
        Warm start: one particle is placed exactly here.
    init_bounds : sequence of (low, high), optional
        Box from which particles are initialised (a shrunken search range
        around a previous estimate); defaults to ``bounds``.
    explore_fraction : float, default 0.0
        Fraction of particles initialised over the whole ``bounds`` even when
        ``init_bounds`` is given, so that a real parameter change is caught.
    v_max : float, default 0.5
        Velocity clamp as a fraction of each dimension's ``bounds`` width.
    tol : float, default 0.0
        Stop when the best cost improved by less than ``tol`` (relative) over
        ``patience`` iterations. 0 runs all iterations.
    patience : int, default 10
    rng : int or numpy.random.Generator, optional
        Seed or generator (SPEC 7). Same seed, same result.
    """

    def __init__(
        self,
        cost: CostFunction,
        bounds: Sequence[tuple[float, float]] | np.ndarray,
        *,
        n_particles: int = 100,
        w: float = 0.7,
        schedule: str | tuple[float, float] = "s-k",
        x0: Sequence[float] | np.ndarray | None = None,
        init_bounds: Sequence[tuple[float, float]] | np.ndarray | None = None,
        explore_fraction: float = 0.0,
        v_max: float = 0.5,
        tol: float = 0.0,
        patience: int = 10,
        rng: int | np.random.Generator | None = None,
    ) -> None:
        box = np.array(bounds, dtype=np.float64)
        if box.ndim != 2 or box.shape[1] != 2 or box.shape[0] < 1:
            raise ValueError(
                f"bounds must be a sequence of (low, high) pairs, got shape {box.shape}"
            )
        if not np.all(np.isfinite(box)) or np.any(box[:, 0] >= box[:, 1]):
            raise ValueError(
                f"bounds need finite low < high in every dimension, got {box.tolist()}"
            )
        if n_particles < 2:
            raise ValueError(f"n_particles must be >= 2, got {n_particles}")
        if not 0.0 <= w < 1.5:
            raise ValueError(f"inertia w must be in [0, 1.5), got {w}")
        if not 0.0 <= explore_fraction <= 1.0:
            raise ValueError(f"explore_fraction must be in [0, 1], got {explore_fraction}")
        if not v_max > 0:
            raise ValueError(f"v_max must be > 0, got {v_max}")
        if tol < 0 or patience < 1:
            raise ValueError(f"need tol >= 0 and patience >= 1, got tol={tol}, patience={patience}")
        coefficients(schedule, 0)  # validates the name

        self.cost = cost
        self.lower = np.ascontiguousarray(box[:, 0])
        self.upper = np.ascontiguousarray(box[:, 1])
        self.n_particles = int(n_particles)
        self.n_dim = box.shape[0]
        self.w = float(w)
        self.schedule = schedule
        self.tol = float(tol)
        self.patience = int(patience)
        self.v_max = float(v_max) * (self.upper - self.lower)
        self.rng = np.random.default_rng(rng)

        init = box if init_bounds is None else np.array(init_bounds, dtype=np.float64)
        if init.shape != box.shape or np.any(init[:, 0] > init[:, 1]):
            raise ValueError(
                f"init_bounds must be {box.shape[0]} (low, high) pairs with low <= high"
            )
        init_lo = np.clip(init[:, 0], self.lower, self.upper)
        init_hi = np.clip(init[:, 1], self.lower, self.upper)

        n_explore = (
            int(round(explore_fraction * self.n_particles)) if init_bounds is not None else 0
        )
        u = self.rng.random((self.n_particles, self.n_dim))
        x = init_lo + u * (init_hi - init_lo)
        if n_explore:
            x[-n_explore:] = self.lower + u[-n_explore:] * (self.upper - self.lower)
        if x0 is not None:
            start = np.asarray(x0, dtype=np.float64)
            if start.shape != (self.n_dim,):
                raise ValueError(f"x0 must have {self.n_dim} elements, got shape {start.shape}")
            x[0] = np.clip(start, self.lower, self.upper)
        # Initial velocities span the initial range, so a tight warm start stays local.
        span = np.maximum(init_hi - init_lo, 1e-12 * (self.upper - self.lower))
        self.v = (self.rng.random((self.n_particles, self.n_dim)) - 0.5) * span
        self.x = np.ascontiguousarray(x)

        c = self._evaluate(self.x)
        self.personal_best = self.x.copy()
        self.personal_cost = np.full(self.n_particles, np.inf)
        self.best_index = kernels.update_personal_best(
            self.x, c, self.personal_best, self.personal_cost
        )
        self.iteration = 0
        self.n_evaluations = self.n_particles
        self.history: list[float] = [self.best_cost]
        self.converged = False

    def _evaluate(self, x: np.ndarray) -> np.ndarray:
        c = np.asarray(self.cost(x), dtype=np.float64)
        if c.shape != (x.shape[0],):
            raise ValueError(
                f"cost function returned shape {c.shape}, expected ({x.shape[0]},): "
                "it must map (n_particles, n_params) to (n_particles,)"
            )
        return c

    @property
    def best_position(self) -> np.ndarray:
        """Best position found so far (a copy)."""
        return self.personal_best[self.best_index].copy()

    @property
    def best_cost(self) -> float:
        """Best cost found so far."""
        return float(self.personal_cost[self.best_index])

    def step(self) -> float:
        """Run one iteration; return the best cost so far."""
        c1, c2 = coefficients(self.schedule, self.iteration)
        r = self.rng.random((2, self.n_particles, self.n_dim))
        gbest = self.personal_best[self.best_index].copy()
        kernels.pso_update(
            self.x, self.v, self.personal_best, gbest, r[0], r[1],
            self.w, c1, c2, self.lower, self.upper, self.v_max,
        )  # fmt: skip
        c = self._evaluate(self.x)
        self.best_index = kernels.update_personal_best(
            self.x, c, self.personal_best, self.personal_cost
        )
        self.iteration += 1
        self.n_evaluations += self.n_particles
        self.history.append(self.best_cost)
        return self.best_cost

    def __iter__(self) -> Iterator[float]:
        while True:
            yield self.step()

    def _stalled(self) -> bool:
        if self.tol <= 0 or len(self.history) <= self.patience:
            return False
        old = self.history[-1 - self.patience]
        new = self.history[-1]
        return bool(old - new <= self.tol * max(abs(old), np.finfo(float).tiny))

    def run(self, max_iterations: int) -> PSOResult:
        """Iterate until ``max_iterations`` or the tolerance stops the search."""
        if max_iterations < 0:
            raise ValueError(f"max_iterations must be >= 0, got {max_iterations}")
        message = f"maximum number of iterations ({max_iterations}) reached"
        for _ in range(max_iterations):
            self.step()
            if self._stalled():
                self.converged = True
                message = (
                    f"best cost improved by less than tol={self.tol:g} (relative) "
                    f"over {self.patience} iterations"
                )
                break
        return self.result(message)

    def result(self, message: str = "") -> PSOResult:
        """Freeze the current state into a :class:`PSOResult`."""
        return PSOResult(
            x=self.best_position,
            cost=self.best_cost,
            n_iterations=self.iteration,
            n_evaluations=self.n_evaluations,
            history=np.array(self.history),
            converged=self.converged,
            message=message,
        )


def minimize(
    cost: CostFunction,
    bounds: Sequence[tuple[float, float]] | np.ndarray,
    *,
    n_particles: int = 100,
    max_iterations: int = 100,
    **options: object,
) -> PSOResult:
    """Minimise a swarm cost with the paper's PSO.

    Parameters
    ----------
    cost : callable
        ``(n_particles, n_params) -> (n_particles,)``.
    bounds : sequence of (low, high)
    n_particles, max_iterations : int
        Swarm size and iteration budget (the paper: 100 x 100 in under 1 s).
    **options
        Keyword options of :class:`ParticleSwarm` (``w``, ``schedule``, ``x0``,
        ``init_bounds``, ``explore_fraction``, ``v_max``, ``tol``, ``patience``, ``rng``).

    Returns
    -------
    PSOResult
    """
    solver = ParticleSwarm(cost, bounds, n_particles=n_particles, **options)  # type: ignore[arg-type]
    return solver.run(max_iterations)
