"""dcobserver: real-time observer of DC-motor electromagnetic parameters.

The numeric kernels live in :mod:`observer.kernels`; the optimizer in
:mod:`observer.pso`; the estimators in :mod:`observer.estimate`.
"""

__version__ = "0.1.0"
