"""Real peers in other processes: a child whose output lines are collected, free ports."""

from __future__ import annotations

import os
import queue
import re
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def child_env(**extra: str) -> dict[str, str]:
    """This environment with the repository importable and no systemd variables."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("NOTIFY_SOCKET", None)
    env.pop("WATCHDOG_USEC", None)
    env.update(extra)
    return env


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Child:
    """A subprocess whose stdout and stderr lines are collected by reader threads.

    ``args`` are the ``dcobserver`` command line (run as ``python -m
    observer.cli``), or with ``script`` a Python file's arguments.
    """

    def __init__(
        self,
        args: Sequence[str],
        env: dict[str, str] | None = None,
        prefix: Sequence[str] = (),
        script: str | os.PathLike[str] | None = None,
    ) -> None:
        program = [str(script)] if script is not None else ["-m", "observer.cli"]
        self.proc = subprocess.Popen(
            [*prefix, sys.executable, *program, *args],
            cwd=REPO, env=env or child_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        self.lines: queue.Queue[tuple[str, str]] = queue.Queue()
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        for name, stream, store in (
            ("out", self.proc.stdout, self.stdout),
            ("err", self.proc.stderr, self.stderr),
        ):
            threading.Thread(target=self._pump, args=(name, stream, store), daemon=True).start()

    def _pump(self, name: str, stream: object, store: list[str]) -> None:
        for line in stream:  # type: ignore[attr-defined]
            store.append(line)
            self.lines.put((name, line))

    def wait_line(self, pattern: str, timeout: float = 60.0, stream: str = "err") -> str:
        """The next line of ``stream`` matching ``pattern``; AssertionError after ``timeout``."""
        deadline = time.monotonic() + timeout
        regex = re.compile(pattern)
        while time.monotonic() < deadline:
            try:
                name, line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.proc.poll() is not None and self.lines.empty():
                    break
                continue
            if name == stream and regex.search(line):
                return line
        tail = "".join(self.stderr[-20:])
        raise AssertionError(f"no line matching {pattern!r} within {timeout} s; stderr:\n{tail}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)
