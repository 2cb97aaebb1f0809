"""Estimation of the winding parameters: motor model, numba kernels, PSO and estimators.

Start with :func:`estimate_field` and :func:`estimate_armature`
(:mod:`observer.estimation.estimate`); the exact discrete winding models and
the swarm costs are the numba kernels of :mod:`observer.estimation.kernels`,
the paper's swarm is :mod:`observer.estimation.pso`, and the machine's
parameters are :mod:`observer.estimation.motor`.

Import rule: this package imports only ``observer.estimation`` and
``observer.config`` (checked by ``tests/test_architecture.py``).

The public names below are imported on first use: ``dcobserver --help`` reads
the motor table and must not load numba for it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from observer.estimation.estimate import CIRCUIT_CHANNELS as CIRCUIT_CHANNELS
    from observer.estimation.estimate import CIRCUITS as CIRCUITS
    from observer.estimation.estimate import CircuitEstimate as CircuitEstimate
    from observer.estimation.estimate import EstimationError as EstimationError
    from observer.estimation.estimate import SearchRange as SearchRange
    from observer.estimation.estimate import armature_search_range as armature_search_range
    from observer.estimation.estimate import estimate_armature as estimate_armature
    from observer.estimation.estimate import estimate_field as estimate_field
    from observer.estimation.estimate import estimate_recording as estimate_recording
    from observer.estimation.estimate import field_search_range as field_search_range
    from observer.estimation.estimate import input_noise_variance as input_noise_variance
    from observer.estimation.motor import MOTORS as MOTORS
    from observer.estimation.motor import P12 as P12
    from observer.estimation.motor import TRACTION_60V as TRACTION_60V
    from observer.estimation.motor import MotorParameters as MotorParameters
    from observer.estimation.pso import SCHEDULES as SCHEDULES
    from observer.estimation.pso import ParticleSwarm as ParticleSwarm
    from observer.estimation.pso import PSOResult as PSOResult
    from observer.estimation.pso import minimize as minimize

#: Public name -> the module of this package that defines it.
_EXPORTS: dict[str, str] = {
    "CIRCUITS": "estimate",
    "CIRCUIT_CHANNELS": "estimate",
    "CircuitEstimate": "estimate",
    "EstimationError": "estimate",
    "SearchRange": "estimate",
    "armature_search_range": "estimate",
    "estimate_armature": "estimate",
    "estimate_field": "estimate",
    "estimate_recording": "estimate",
    "field_search_range": "estimate",
    "input_noise_variance": "estimate",
    "MOTORS": "motor",
    "P12": "motor",
    "TRACTION_60V": "motor",
    "MotorParameters": "motor",
    "SCHEDULES": "pso",
    "ParticleSwarm": "pso",
    "PSOResult": "pso",
    "minimize": "pso",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
