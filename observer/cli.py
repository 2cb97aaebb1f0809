"""The ``dcobserver`` command line.

Each subcommand lives in its own module with two functions::

    def configure(parser: argparse.ArgumentParser) -> None: ...
    def main(args: argparse.Namespace) -> int: ...

and is registered in :data:`COMMANDS` by module name, imported only when it
runs, so ``dcobserver --help`` stays fast (numba is not imported for it).
User errors (bad files, bad config, bad values) print one line and exit 2;
no traceback reaches the user.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import signal
import sys
import threading
import warnings
from collections.abc import Sequence
from typing import Any, NoReturn

from observer import __version__
from observer.service.threads import one_blas_thread

one_blas_thread()  # before numpy loads its BLAS (observer/service/threads.py says why)

#: name -> (module, one-line help). Keep in the order users meet them.
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("observer.commands.simulate", "write a simulated recording of a DC drive"),
    "estimate": (
        "observer.commands.estimate",
        "estimate field and armature parameters of a recording",
    ),
    "run": ("observer.commands.run", "run the real-time observer daemon (default: the demo)"),
    "subscribe": (
        "observer.commands.subscribe",
        "live table of the estimates of every drive and motor (Zenoh)",
    ),
    "router": (
        "observer.commands.router",
        "a Zenoh router for a fleet of daemons, with TLS, passwords and access control",
    ),
    "replay": (
        "observer.commands.replay",
        "run the observer over a recording, as fast as possible",
    ),
    "recover": ("observer.commands.recover", "rewrite a truncated MCAP log as a valid one"),
    "fake-drive": (
        "observer.commands.fake_drive",
        "serve a simulated drive over CAN, serial or Modbus (no hardware needed)",
    ),
    "diagnose": (
        "observer.commands.diagnose",
        "locate model mismatch, name the missing physics, fit it and show the improvement",
    ),
}

EXIT_USAGE = 2
#: The reader of stdout closed the pipe: 128 + SIGPIPE, what a shell reports for such a tool.
EXIT_BROKEN_PIPE = 141


class UserError(Exception):
    """An error the user can fix; printed as one line, exit status 2."""


def _user_error_types() -> tuple[type[BaseException], ...]:
    # Under ``python -m observer.cli`` this module is ``__main__`` and the
    # commands raise ``observer.cli.UserError``, a different class object.
    from observer.cli import UserError as imported_user_error
    from observer.config import ConfigError
    from observer.estimation import EstimationError

    types: list[type[BaseException]] = [
        UserError,
        imported_user_error,
        EstimationError,
        ConfigError,
    ]
    try:
        from observer.recording import RecordingError

        types.append(RecordingError)
    except ImportError:  # pragma: no cover - recording is part of the package
        pass
    return tuple(types)


class _Parser(argparse.ArgumentParser):
    """Usage errors in one line, like every other bad input (the usage is in --help)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows ``(default: X)`` only where it says something: not for None, flags, or when
    the help text already names the default."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or "default" in text.lower()
            or default is None
            or default is argparse.SUPPRESS
            or isinstance(default, bool)
            or action.option_strings == []
            and action.nargs not in ("?", "*")
        ):
            return text
        return super()._get_help_string(action)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="dcobserver",
        description="Real-time observer of DC-motor winding parameters (R, L of field and "
        "armature) by particle-swarm output-error identification.",
    )
    parser.add_argument("--version", action="version", version=f"dcobserver {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        p = sub.add_parser(
            name, help=help_text, description=help_text, formatter_class=_HelpFormatter,
        )  # fmt: skip
        p.set_defaults(_module=module_name)
        _configure(p, module_name)
    return parser


def _configure(parser: argparse.ArgumentParser, module_name: str) -> None:
    module = importlib.import_module(module_name)
    module.configure(parser)


def setup_logging(verbosity: int) -> None:
    """One stderr handler that reads well in journald (no timestamps: journald adds them)."""
    level = logging.WARNING - 10 * min(verbosity, 2) if verbosity else logging.INFO
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``dcobserver`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_module", None):
        parser.print_help()
        return EXIT_USAGE
    setup_logging(args.verbose)
    # A record a library's thread emits after its stream is closed (dask.distributed's, at the
    # exit of `replay --scheduler`) must not print "--- Logging error ---" and a traceback.
    logging.raiseExceptions = False
    module = importlib.import_module(args._module)
    previous = _terminate_like_interrupt()
    try:
        with warnings.catch_warnings():
            if args.verbose < 2 and not sys.warnoptions:
                # NaN and overflow on the way are handled (a parameter the data does not
                # identify is flagged, an impossible input is an error): numpy's notes
                # about them are for -vv, not for the user.
                warnings.simplefilter("ignore", RuntimeWarning)
            code = int(module.main(args) or 0)
            sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
            return code
    except BrokenPipeError:
        # The reader went away (`dcobserver replay --json rec.mcap | head`): it has what it
        # wanted. Stop quietly, as a shell tool killed by SIGPIPE does, and point stdout at
        # /dev/null so that the interpreter's last flush does not fail again.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except _user_error_types() as exc:
        print(f"dcobserver {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        # Sizes are checked where an option sets them (--particles, --duration x --rate);
        # a recording or an option beyond this machine still ends in one line.
        print(
            f"dcobserver {args.command}: error: out of memory: the recording or the options "
            "need more than this machine has",
            file=sys.stderr,
        )  # fmt: skip
        return EXIT_USAGE
    except KeyboardInterrupt:
        return 130
    except _Terminated:
        return 143
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


class _Terminated(BaseException):
    """SIGTERM, raised like KeyboardInterrupt so that output files are cleaned up."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated


def _terminate_like_interrupt() -> Any:
    """Make SIGTERM unwind the stack (``finally`` blocks, atomic outputs discard their
    temporary files) instead of killing the process where it stands. Commands that
    handle SIGTERM themselves (``run``, ``fake-drive``) install their own handler."""
    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:
        return None
    return signal.signal(signal.SIGTERM, _raise_terminated)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
