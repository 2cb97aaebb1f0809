"""The swarm search of one winding over ``log10 (R, L)``, restarted once from a wall."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from observer.estimation.pso import ParticleSwarm, PSOResult
from observer.estimation.ranges import SearchRange

log = logging.getLogger(__name__)


def run_swarm(
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
