"""Linear algebra in one thread, for the processes that estimate windows.

A window's matrices are small (a few columns, 10^3-10^4 rows): OpenBLAS gains
nothing from threads there, and its threads spin between calls on the core the
rest of the work needs. Measured on the converter-fed P-12 at 10 kHz (AMD EPYC,
2 cores): a window 27.9 -> 24.5 ms in one process; with the armature in a second
process (:mod:`observer.service.circuit_worker`) 22-23 -> 18.7 ms, p99 44-52 ->
27 ms. The results are the same to the bit. It has to happen before numpy loads
its BLAS: the ``dcobserver`` command does it first thing; a variable the user set
is kept.
"""

from __future__ import annotations

import os

#: The variables each BLAS (and OpenMP) reads for its thread count, and their value here.
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def one_blas_thread() -> None:
    """Ask for one BLAS thread (unless the environment already says), before numpy loads."""
    for name, value in ONE_THREAD.items():
        os.environ.setdefault(name, value)
