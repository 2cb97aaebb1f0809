"""Model-discrepancy diagnosis: where the plain winding model misses, and which physics explains it.

Start with :func:`observer.diagnosis.diagnose.diagnose`, whose stages
(baseline, noise floor, locate, candidates, selection, verdict) are functions
of their own; the candidate physics is the composable library of
:mod:`observer.diagnosis.effects`, its numba model :mod:`observer.diagnosis.kernels`,
and the HTML page :mod:`observer.diagnosis.report`.

Import rule: this package may import ``observer.diagnosis``,
``observer.estimation``, ``observer.recording`` and ``observer.config``;
nothing of the service or the simulator (checked by ``tests/test_architecture.py``).
"""
