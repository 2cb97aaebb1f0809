"""Output files that appear whole or not at all.

Every file dcobserver writes for a user (recordings, recovered logs, reports,
JSON results, rotated daemon logs) is written under a temporary name in the
destination's own folder, flushed and ``fsync``-ed, and only then renamed to
its final name (a rename within one file system is atomic). A crash, a full
disk, an exception or Ctrl-C while writing leaves the final name untouched:
either the old file or no file, never a partial one. The temporary file is
removed on any error, ``KeyboardInterrupt`` included; a hard kill can leave
one behind, recognisable by :func:`is_temporary` (a hidden name with
:data:`TEMP_MARKER` in it).

Three ways in, by what the writer needs::

    with atomic_open("out.json", "w") as f:        # a text or binary stream
        f.write(text)

    with AtomicFile("log.mcap") as out:            # the stream and the names
        writer = Writer(out.stream)
        ...                                        # commit() on leaving

    log = AtomicFile("log.mcap")                   # a long-lived file: the
    ...                                            # daemon's log until rotation
    log.commit()                                   # or log.discard()
"""

from __future__ import annotations

import contextlib
import io
import os
import secrets
import signal
from collections.abc import Iterator
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Final, Literal

PathArg = str | os.PathLike[str]

TEMP_MARKER: Final = ".partial-"
"""Part of every temporary name: ``.NAME.partial-XXXXXXXX`` next to ``NAME``."""


def temporary_path(path: PathArg) -> Path:
    """A fresh temporary name for ``path``, in the same folder and hidden.

    Parameters
    ----------
    path : str or os.PathLike
        The final file name.

    Returns
    -------
    pathlib.Path
        ``<folder>/.<name>.partial-<8 hex digits>``.
    """
    final = Path(path)
    return final.with_name(f".{final.name}{TEMP_MARKER}{secrets.token_hex(4)}")


def is_temporary(path: PathArg) -> bool:
    """Whether ``path`` is a name :func:`temporary_path` makes (a leftover of a killed writer)."""
    name = Path(path).name
    return name.startswith(".") and TEMP_MARKER in name


def final_path(path: PathArg) -> Path:
    """The final name a temporary name stands for (``path`` itself if it is not one)."""
    p = Path(path)
    if not is_temporary(p):
        return p
    return p.with_name(p.name[1:].rsplit(TEMP_MARKER, 1)[0])


@contextlib.contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT and SIGTERM for the block (where the platform allows): their handlers run
    right after it, at a point where the caller's state is consistent."""
    sigs = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    except (AttributeError, OSError, ValueError):  # no pthread_sigmask here
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable; some file systems cannot, which is fine."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class AtomicFile:
    """A binary file written under a temporary name and renamed to ``path`` by :meth:`commit`.

    Parameters
    ----------
    path : str or os.PathLike
        The final name. Its folder must exist.
    overwrite : bool
        Whether :meth:`commit` may replace an existing ``path``. When False,
        :meth:`commit` raises :class:`FileExistsError` (and discards the
        temporary file) if ``path`` appeared meanwhile.

    Attributes
    ----------
    path : pathlib.Path
        The final name.
    temp_path : pathlib.Path
        Where the bytes are until :meth:`commit`.
    stream : IO[bytes]
        The open temporary file.

    Raises
    ------
    OSError
        If the temporary file cannot be created (folder missing, not writable).

    Notes
    -----
    Used as a context manager it commits when the block ends normally and
    discards on any exception (``KeyboardInterrupt`` too), which it re-raises.
    The file is created with mode ``0o666`` less the umask, like ``open``.
    """

    def __init__(self, path: PathArg, *, overwrite: bool = True) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self.temp_path = temporary_path(self.path)
        self._done = True  # nothing to clean up until the file exists
        # Ctrl-C or SIGTERM between creating the file and recording that it exists would leave
        # it behind: they are deferred until this object can discard it.
        with _signals_deferred():
            fd = os.open(self.temp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            try:
                self.stream: IO[bytes] = os.fdopen(fd, "wb")
            except BaseException:
                os.close(fd)
                self._unlink_temp()
                raise
            self._done = False

    @property
    def closed(self) -> bool:
        """Whether :meth:`commit`, :meth:`discard` or :meth:`leave` has run."""
        return self._done

    def commit(self) -> Path:
        """Flush, ``fsync``, close and rename the file to its final name.

        Returns
        -------
        pathlib.Path
            The final name.

        Raises
        ------
        OSError
            If flushing or renaming fails (e.g. a full disk); the temporary
            file is then removed and the final name left as it was.
        FileExistsError
            With ``overwrite=False``, if the final name exists.
        ValueError
            If the file was already committed or discarded.
        """
        if self._done:
            raise ValueError(f"{self.path}: already committed or discarded")
        try:
            if not self.stream.closed:
                self.stream.flush()
                os.fsync(self.stream.fileno())
                self.stream.close()
            if self.overwrite:
                os.replace(self.temp_path, self.path)
            else:
                self._rename_no_overwrite()
        except BaseException:
            self.discard()
            raise
        self._done = True
        _fsync_folder(self.path.parent)
        return self.path

    def _rename_no_overwrite(self) -> None:
        try:
            # A hard link fails if the name exists: no window in which a file
            # created meanwhile could be replaced.
            os.link(self.temp_path, self.path)
        except FileExistsError:
            raise
        except OSError:  # a file system without hard links
            if self.path.exists():
                raise FileExistsError(17, "File exists", str(self.path)) from None
            os.rename(self.temp_path, self.path)
            return
        self._unlink_temp()

    def discard(self) -> None:
        """Close and remove the temporary file; the final name is not touched. Idempotent."""
        if self._done:
            return
        self._done = True
        with contextlib.suppress(OSError):
            self.stream.close()
        self._unlink_temp()

    def leave(self) -> Path:
        """Close the file but leave it under its temporary name; the final name is not touched.

        For a long-lived file whose partial content is worth more than nothing
        (the daemon's log after a write error): it is found again by
        :func:`is_temporary` and :func:`final_path` and recovered later. Idempotent.

        Returns
        -------
        pathlib.Path
            The temporary name the bytes stay under.
        """
        if not self._done:
            self._done = True
            with contextlib.suppress(OSError):
                self.stream.close()
        return self.temp_path

    def _unlink_temp(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.temp_path)

    def __enter__(self) -> AtomicFile:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            if not self._done:
                self.commit()
        else:
            self.discard()

    def __del__(self) -> None:
        # An AtomicFile dropped without commit() must not leave its temporary file.
        with contextlib.suppress(Exception):
            if not getattr(self, "_done", True):
                self.discard()


@contextlib.contextmanager
def atomic_open(
    path: PathArg,
    mode: Literal["w", "wb", "wt"] = "w",
    *,
    encoding: str = "utf-8",
    newline: str | None = None,
    overwrite: bool = True,
) -> Iterator[IO[Any]]:
    """Open ``path`` for writing; it appears under its name only when the block ends normally.

    Parameters
    ----------
    path : str or os.PathLike
        The final name.
    mode : {"w", "wt", "wb"}
        Text (with ``encoding`` and ``newline`` as for :func:`open`) or binary.
    encoding, newline : str
        Text modes only.
    overwrite : bool
        See :class:`AtomicFile`.

    Yields
    ------
    IO
        The stream to write to.

    Raises
    ------
    OSError
        If the file cannot be created or completed; nothing is left behind.
    """
    if mode not in ("w", "wt", "wb"):
        raise ValueError(f"mode must be 'w', 'wt' or 'wb', got {mode!r}")
    with AtomicFile(path, overwrite=overwrite) as out:
        if mode == "wb":
            yield out.stream
        else:
            text = io.TextIOWrapper(out.stream, encoding=encoding, newline=newline)
            try:
                yield text
                text.flush()
            finally:
                text.detach()  # the AtomicFile closes the binary stream


def check_writable(path: PathArg) -> None:
    """Raise unless a file can be written at ``path`` (call it before long work).

    Creates and removes a temporary file in the destination's folder, so it
    checks what writing will need: the folder exists and is writable.

    Raises
    ------
    OSError
        As creating the file there would (``FileNotFoundError`` for a missing
        folder, ``PermissionError``, ``IsADirectoryError`` for a folder given
        as ``path``).
    """
    p = Path(path)
    if p.is_dir():
        raise IsADirectoryError(21, "Is a directory", str(p))
    probe = AtomicFile(p)
    probe.discard()
