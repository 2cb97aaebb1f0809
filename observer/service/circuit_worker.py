"""A second process that estimates the armature while the observer's own estimates the field.

The two circuits of a window are independent: each estimate reads only its own
channels, its own warm start (taken from the tracked state *before* the window)
and its own chain state, and the tracker is stepped once both are in. So the
armature's estimator can run in another process while this one runs the
field's, and the window's results are those of running them one after the
other, to the bit (the estimators are deterministic functions of their
arguments, seed included). Threads would not do: the Python between the numba
kernels holds the interpreter lock (two threads: 0.9-1.3x on this work).

The worker is a fresh interpreter (``python -m observer.service.circuit_worker``,
not a ``fork``: numba's OpenMP layer does not survive ``fork`` after a parallel
call, and the daemon has threads; nor multiprocessing's ``spawn``, which runs
the parent's main script again in the child), talking over a socket pair with
multiprocessing's pickling :class:`~multiprocessing.connection.Connection`. It
loads the kernels first (:func:`~observer.service.window_observer.warm_up_kernels`)
and says when it is ready; until then, and whenever it fails, the observer
estimates both circuits itself. It ignores SIGINT (the terminal's Ctrl-C is the
parent's to handle) and dies with its parent (``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from multiprocessing.connection import Connection
from typing import Any

from observer.service.threads import ONE_THREAD

log = logging.getLogger(__name__)

#: How long :meth:`CircuitWorker.result` waits for an estimate before it gives the worker
#: up (s): a window's estimate takes milliseconds; a worker this late is stuck.
RESULT_TIMEOUT_S = 30.0

_PR_SET_PDEATHSIG = 1


class WorkerFailed(RuntimeError):
    """The worker process died or stopped answering; the caller estimates the circuit itself."""


def parallel_wanted(setting: str) -> bool:
    """Whether ``[observer] parallel_circuits`` asks for the worker here.

    ``on`` and ``off`` say so; ``auto`` is on where this process may run on two
    or more CPUs, unless the environment says ``DCOBSERVER_PARALLEL_CIRCUITS=off``
    (the test suite does, so that its hundreds of short observers do not each
    start a process).
    """
    if setting in ("on", "off"):
        return setting == "on"
    if os.environ.get("DCOBSERVER_PARALLEL_CIRCUITS", "").strip().lower() in ("off", "0"):
        return False
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return cpus >= 2


class CircuitWorker:
    """One worker process that runs a circuit's estimator on request.

    :meth:`ready` is false until the worker has loaded the kernels; :meth:`submit`
    sends one estimate's arguments (the observer's prepared circuit, run there by
    :func:`~observer.service.window_observer.run_estimator`), :meth:`result` waits for
    its answer (the estimate, or the estimator's exception raised here). Any failure of
    the process itself raises :class:`WorkerFailed` and leaves the worker closed.
    """

    def __init__(self) -> None:
        ours, theirs = socket.socketpair()
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "observer.service.circuit_worker", str(theirs.fileno())],
            pass_fds=(theirs.fileno(),),
            stdin=subprocess.DEVNULL,
            # Its linear algebra in one thread: OpenBLAS's threads spin between calls on
            # the core this process works on (observer/service/threads.py).
            env={**os.environ, **ONE_THREAD},
        )
        theirs.close()
        self._conn = Connection(ours.detach())
        self._ready = False
        self._pending = False
        self.closed = False
        self.warm_up_s = float("nan")

    @property
    def pid(self) -> int | None:
        return self._proc.pid

    def ready(self) -> bool:
        """True once the worker has loaded the kernels (never blocks)."""
        if self._ready or self.closed:
            return self._ready and not self.closed
        try:
            if self._conn.poll():
                kind, value = self._conn.recv()
                if kind == "ready":
                    self._ready = True
                    self.warm_up_s = float(value)
                    log.info(
                        "field and armature estimated in two processes (armature: pid %s, "
                        "kernels loaded in %.1f s)", self._proc.pid, value,
                    )  # fmt: skip
            elif self._proc.poll() is not None:
                raise EOFError
        except (EOFError, OSError):
            self._fail("exited before it was ready")
        return self._ready

    def wait_ready(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for the worker to load its kernels; whether it did."""
        deadline = time.monotonic() + timeout_s
        while not self.ready() and not self.closed:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            with contextlib.suppress(OSError, EOFError):
                self._conn.poll(min(left, 0.5))
        return self.ready()

    def submit(self, job: Any) -> None:
        """Send one circuit's prepared estimate (picklable) to the worker."""
        if self.closed or self._pending:
            raise WorkerFailed("the worker is closed or busy")
        try:
            self._conn.send(("estimate", job))
        except (OSError, ValueError) as exc:
            self._fail(f"could not be sent a window: {exc}")
            raise WorkerFailed(str(exc)) from exc
        self._pending = True

    def result(self) -> Any:
        """The submitted estimate (or its exception, raised), waiting for it."""
        if not self._pending:
            raise WorkerFailed("nothing submitted")
        self._pending = False
        try:
            if not self._conn.poll(RESULT_TIMEOUT_S):
                self._fail(f"gave no answer within {RESULT_TIMEOUT_S:g} s")
                raise WorkerFailed("timeout")
            kind, value = self._conn.recv()
        except (EOFError, OSError) as exc:
            self._fail(f"died ({type(exc).__name__})")
            raise WorkerFailed("died") from exc
        if kind == "error":
            raise value
        return value

    def _fail(self, why: str) -> None:
        log.warning(
            "circuit worker (pid %s) %s: both circuits are estimated in this process from now on",
            self._proc.pid, why,
        )  # fmt: skip
        self.close()

    def close(self) -> None:
        """Stop the worker now (a warm-up or an estimate in progress is abandoned)."""
        if self.closed:
            return
        self.closed = True
        with contextlib.suppress(OSError, ValueError):
            self._conn.send(("stop",))
        with contextlib.suppress(OSError):
            self._conn.close()
        try:
            self._proc.wait(0.5)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(2.0)


def _serve(conn: Connection) -> None:
    """The worker's loop: load the kernels, then estimate what is sent until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    from observer.service.window_observer import run_estimator, warm_up_kernels

    started = time.monotonic()
    warm_up_kernels()
    try:
        conn.send(("ready", time.monotonic() - started))
        while True:
            message = conn.recv()
            if message[0] != "estimate":
                return
            try:
                est = run_estimator(message[1])
            except Exception as exc:  # the estimator's own error: the parent handles it
                conn.send(("error", exc))
                continue
            conn.send(("ok", est))
    except (EOFError, OSError, KeyboardInterrupt):
        return


if __name__ == "__main__":
    _serve(Connection(int(sys.argv[1])))
