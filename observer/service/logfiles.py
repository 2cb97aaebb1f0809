"""Housekeeping of the daemon's log folder: retention by total size and by age.

The files of one daemon are ``<stem>-<UTC stamp>-<pid>-<n>.mcap`` with ``stem``
``<prefix>-<drive_id>`` or ``<prefix>-<drive_id>-<motor_id>`` (:func:`log_stem`);
their names sort by the time they were started. :class:`Retention` deletes
the oldest of them until the rest fit the budget, never the file being
written nor the newest one, logs every deletion and counts them for the
daemon's health.
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


def log_stem(prefix: str, drive_id: str, motor_id: str = "") -> str:
    """The start of one daemon's log file names: ``prefix-drive_id[-motor_id]``."""
    return "-".join(part for part in (prefix, drive_id, motor_id) if part)


@dataclass(frozen=True)
class _LogFile:
    path: Path
    size: int
    mtime: float


class Retention:
    """Keeps the log files of one daemon (a drive, or a motor of it) within a size and age budget.

    Parameters
    ----------
    folder : pathlib.Path
        The log folder.
    stem : str
        :func:`log_stem`: only ``<stem>-<UTC stamp>-<pid>-<n>.mcap`` files are
        this daemon's (other drives' and motors' sharing the folder are left alone).
    max_total_bytes : int
        Largest total size of this drive's files, the open one included; 0: no limit.
    max_age_s : float
        Files last modified longer ago than this are deleted; 0: no limit.
    """

    def __init__(self, folder: Path, stem: str, *, max_total_bytes: int, max_age_s: float) -> None:
        self.folder = Path(folder)
        self.stem = stem
        self._names = re.compile(re.escape(stem) + r"-\d{8}T\d{6}-\d+-\d+\.mcap")
        self.max_total_bytes = int(max_total_bytes)
        self.max_age_s = float(max_age_s)
        self._lock = threading.Lock()
        self._health: dict[str, Any] = {
            "deleted_files": 0,
            "deleted_bytes": 0,
            "last_deleted": "",
            "total_bytes": 0,
            "files": 0,
        }

    def health(self) -> dict[str, Any]:
        """Counters: files and bytes deleted, the last one, this drive's files and bytes now."""
        with self._lock:
            return dict(self._health)

    def owns(self, name: str) -> bool:
        """Whether a file name is one of this daemon's log files."""
        return self._names.fullmatch(name) is not None

    def files(self) -> list[_LogFile]:
        """This daemon's log files, oldest first (by name: the names start with the UTC time)."""
        found = []
        try:
            entries = list(os.scandir(self.folder))
        except FileNotFoundError:
            return []
        for entry in entries:
            if not self.owns(entry.name):
                continue
            try:
                stat = entry.stat()
            except FileNotFoundError:  # deleted meanwhile
                continue
            found.append(_LogFile(Path(entry.path), stat.st_size, stat.st_mtime))
        return sorted(found, key=lambda f: (f.path.name, f.mtime))

    def enforce(self, keep: Path | None = None, now: float | None = None) -> list[Path]:
        """Delete the oldest files beyond the budget; never ``keep`` (the open file) nor the newest.

        Returns
        -------
        list of pathlib.Path
            The files deleted.
        """
        files = self.files()
        now = time.time() if now is None else now
        total = sum(f.size for f in files)
        deleted = []
        for f in files[:-1]:  # the newest file holds the newest data: it always stays
            if keep is not None and f.path == keep:
                continue
            too_old = self.max_age_s > 0 and now - f.mtime > self.max_age_s
            too_big = self.max_total_bytes > 0 and total > self.max_total_bytes
            if not (too_old or too_big):
                continue
            try:
                f.path.unlink()
            except FileNotFoundError:
                pass
            total -= f.size
            deleted.append(f.path)
            reason = (
                f"older than {self.max_age_s / 86400:g} days"
                if too_old
                else (f"the drive's logs exceed {self.max_total_bytes / 1e9:g} GB")
            )
            log.info("MCAP log: deleted %s (%.1f MB): %s", f.path, f.size / 1e6, reason)
            with self._lock:
                self._health["deleted_files"] += 1
                self._health["deleted_bytes"] += f.size
                self._health["last_deleted"] = str(f.path)
        with self._lock:
            self._health["total_bytes"] = total
            self._health["files"] = len(files) - len(deleted)
        return deleted
