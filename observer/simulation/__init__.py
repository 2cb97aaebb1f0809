"""Simulated DC drives: recordings in rope-shovel-like operation, and endless sample streams.

Start with :func:`observer.simulation.simulate.simulate` (the plant, its duty
cycle, sensor noise and the drive's cascade controller); the plant's numba
kernels are in :mod:`observer.simulation.kernels`, physics the plain model
leaves out in :mod:`observer.simulation.effects_sim`, and the fake drives'
endless stream in :mod:`observer.simulation.drive_stream`.

Import rule: this package may import ``observer.simulation``,
``observer.estimation`` (the motor's parameters), ``observer.recording`` and
``observer.config``; nothing of the service or the diagnosis (checked by
``tests/test_architecture.py``).
"""
