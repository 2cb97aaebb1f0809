"""dcobserver: real-time observer of DC-motor electromagnetic parameters.

The house, by folder (docs/architecture.md has the picture):

* :mod:`observer.estimation` -- the motor model, numba kernels, PSO and the
  winding estimators: where a window is estimated;
* :mod:`observer.recording` -- the in-memory recording and its CSV / MCAP files;
* :mod:`observer.service` -- ring buffer, sliding-window observer, daemon and
  its sinks (Zenoh, MCAP log, sd_notify): where a sample enters and leaves;
* :mod:`observer.simulation` -- the drive simulator and its streaming form;
* :mod:`observer.diagnosis` -- what the plain model misses, and the report;
* :mod:`observer.config` and :mod:`observer.cli` (with :mod:`observer.commands`),
  which everything may reach.
"""

__version__ = "0.1.0"
