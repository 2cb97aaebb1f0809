"""Benchmarks and the paper's table (run as ``python -m bench.<script>``; never run by pytest)."""

from observer.service.threads import one_blas_thread

# Every bench run as the service runs: BLAS in one thread (observer/service/threads.py),
# set before a bench module imports numpy.
one_blas_thread()
