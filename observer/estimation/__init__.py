"""Estimation of the winding parameters: motor model, numba kernels, PSO and estimators.

Start with :func:`estimate_field` (:mod:`~observer.estimation.field`) and
:func:`estimate_armature` (:mod:`~observer.estimation.armature`, four stages:
swarm, polish, errors-in-variables compensation, uncertainty), and
:func:`estimate_recording` (:mod:`~observer.estimation.estimate`) for a whole
recording. They build on the search ranges and signal checks of
:mod:`~observer.estimation.ranges`, the swarm of :mod:`~observer.estimation.swarm`
(the paper's PSO is :mod:`~observer.estimation.pso`), the Levenberg-Marquardt
polish of :mod:`~observer.estimation.polish` and the bounds of
:mod:`~observer.estimation.uncertainty`; they return a
:class:`~observer.estimation.result.CircuitEstimate`. Which of its parameters
the data identifies is :mod:`~observer.estimation.identifiability`; whether the
recording and the estimates can be a DC motor's at all (units, signs, swapped
channels) is :mod:`~observer.estimation.plausibility`. The exact discrete winding
models and swarm costs are the numba kernels of :mod:`~observer.estimation.kernels`;
the machine's parameters are :mod:`~observer.estimation.motor`.

Import rule: this package imports only ``observer.estimation`` and
``observer.config`` (checked by ``tests/test_architecture.py``).

The public names below are imported on first use: ``dcobserver --help`` reads
the motor table and must not load numba for it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from observer.estimation.armature import estimate_armature as estimate_armature
    from observer.estimation.estimate import CIRCUIT_CHANNELS as CIRCUIT_CHANNELS
    from observer.estimation.estimate import CIRCUITS as CIRCUITS
    from observer.estimation.estimate import estimate_recording as estimate_recording
    from observer.estimation.field import estimate_field as estimate_field
    from observer.estimation.identifiability import Identification as Identification
    from observer.estimation.identifiability import identify as identify
    from observer.estimation.motor import MOTORS as MOTORS
    from observer.estimation.motor import P12 as P12
    from observer.estimation.motor import TRACTION_60V as TRACTION_60V
    from observer.estimation.motor import MotorParameters as MotorParameters
    from observer.estimation.plausibility import Finding as Finding
    from observer.estimation.plausibility import check_data as check_data
    from observer.estimation.plausibility import check_estimates as check_estimates
    from observer.estimation.pso import SCHEDULES as SCHEDULES
    from observer.estimation.pso import ParticleSwarm as ParticleSwarm
    from observer.estimation.pso import PSOResult as PSOResult
    from observer.estimation.pso import minimize as minimize
    from observer.estimation.ranges import EstimationError as EstimationError
    from observer.estimation.ranges import SearchRange as SearchRange
    from observer.estimation.ranges import armature_search_range as armature_search_range
    from observer.estimation.ranges import field_search_range as field_search_range
    from observer.estimation.result import CircuitEstimate as CircuitEstimate
    from observer.estimation.uncertainty import input_noise_variance as input_noise_variance

#: Public name -> the module of this package that defines it.
_EXPORTS: dict[str, str] = {
    "estimate_armature": "armature",
    "CIRCUITS": "estimate",
    "CIRCUIT_CHANNELS": "estimate",
    "estimate_recording": "estimate",
    "estimate_field": "field",
    "Identification": "identifiability",
    "identify": "identifiability",
    "Finding": "plausibility",
    "check_data": "plausibility",
    "check_estimates": "plausibility",
    "MOTORS": "motor",
    "P12": "motor",
    "TRACTION_60V": "motor",
    "MotorParameters": "motor",
    "SCHEDULES": "pso",
    "PSOResult": "pso",
    "ParticleSwarm": "pso",
    "minimize": "pso",
    "EstimationError": "ranges",
    "SearchRange": "ranges",
    "armature_search_range": "ranges",
    "field_search_range": "ranges",
    "CircuitEstimate": "result",
    "input_noise_variance": "uncertainty",
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
