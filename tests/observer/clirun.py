"""The CLI run in the test's own process: tens of milliseconds where a subprocess takes seconds.

For what does not need a process of its own (signals, Zenoh sessions, what Python prints
at exit); the result looks like :class:`subprocess.CompletedProcess`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import subprocess
import warnings
from pathlib import Path

from observer.cli import main


def in_process(*argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """``dcobserver ARGV`` in this process; any exception but the CLI's own exit propagates.

    Python warnings are appended to ``stderr``, as a process would print them.
    """
    out, err = io.StringIO(), io.StringIO()
    root = logging.getLogger()
    saved = (root.handlers[:], root.level)
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with (
            contextlib.redirect_stdout(out),
            contextlib.redirect_stderr(err),
            warnings.catch_warnings(record=True) as caught,
        ):
            warnings.simplefilter("default")  # what a process shows on its stderr
            try:
                code = main(list(argv))
            except SystemExit as exc:  # argparse: --help, usage errors
                code = int(exc.code or 0)
        for w in caught:
            err.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno))
    finally:
        os.chdir(here)
        root.handlers[:], root.level = saved[0], saved[1]
    return subprocess.CompletedProcess(list(argv), code, out.getvalue(), err.getvalue())
