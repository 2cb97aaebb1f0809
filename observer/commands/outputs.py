"""Output files of the commands: checked before the work starts, written whole or not at all.

Not a command (it is not in :data:`observer.cli.COMMANDS`): the helpers the
commands share for ``--json``, ``--report`` and ``--png`` files.
"""

from __future__ import annotations

import os
from collections.abc import Iterable


def check_input(path: str) -> None:
    """Raise a one-line error unless ``path`` is a file to read (not missing, not a folder).

    Raises
    ------
    observer.cli.UserError
        ``"rec.mcap: file not found"``, ``"logs: a directory, not a file"``.
    """
    from observer.cli import UserError

    if os.path.isfile(path):
        return
    if os.path.isdir(path):
        raise UserError(f"{path}: a directory, not a file")
    raise UserError(f"{path}: {'not a regular file' if os.path.exists(path) else 'file not found'}")


def check_outputs(*pairs: tuple[str, str | None], inputs: Iterable[str] = ()) -> None:
    """Raise a one-line error unless every given output path can be written.

    Call before long work, so a typo in a folder name fails in milliseconds,
    not after the work.

    Parameters
    ----------
    *pairs : (option, path or None)
        e.g. ``("--report", args.report)``; ``None`` paths are skipped.
    inputs : iterable of str
        Files the command reads (the recording, a config): an output naming one
        of them is an error (it would overwrite the recording with a report).

    Raises
    ------
    observer.cli.UserError
        ``"--report /no/such/x.html: cannot write: No such file or directory"``.
    """
    from observer.cli import UserError
    from observer.recording import check_writable

    seen: dict[str, str] = {}
    for option, path in pairs:
        if path is None:
            continue
        if path in seen:
            raise UserError(f"{seen[path]} and {option} name the same file {path}")
        seen[path] = option
        for source in inputs:
            if os.path.exists(path) and os.path.exists(source) and os.path.samefile(path, source):
                raise UserError(
                    f"{option} {path} is the input {source} itself: writing it would destroy it"
                )
        try:
            check_writable(path)
        except OSError as exc:
            raise UserError(f"{option} {path}: cannot write: {exc.strerror or exc}") from None


def write_text(path: str, text: str | Iterable[str]) -> None:
    """Write ``text`` to ``path`` atomically (UTF-8); a one-line error if that fails.

    Raises
    ------
    observer.cli.UserError
    """
    from observer.cli import UserError
    from observer.recording import atomic_open

    try:
        with atomic_open(path, "w") as f:
            if isinstance(text, str):
                f.write(text)
            else:
                f.writelines(text)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


def write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically; a one-line error if that fails.

    Raises
    ------
    observer.cli.UserError
    """
    from observer.cli import UserError
    from observer.recording import atomic_open

    try:
        with atomic_open(path, "wb") as f:
            f.write(data)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None
