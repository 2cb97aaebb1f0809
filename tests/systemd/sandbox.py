"""Run a command under a unit's system-call filter and address families, without systemd.

    python sandbox.py UNIT.service -- PROGRAM ARGS...

The unit's ``SystemCallFilter=`` lines (an allow list, then ``~`` deny lists),
``SystemCallErrorNumber=`` and ``RestrictAddressFamilies=`` are read, the groups
expanded by ``systemd-analyze syscall-filter``, and the resulting seccomp
filter is loaded with libseccomp (which systemd itself uses) before PROGRAM is
executed: what the unit's daemon may and may not call, checked here where
systemd is not PID 1. Other sandboxing (namespaces, devices) is not emulated.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import re
import socket
import subprocess
import sys
from functools import cache
from pathlib import Path

SCMP_ACT_ALLOW = 0x7FFF0000
SCMP_CMP_EQ = 4
#: Always permitted by systemd whatever the filter says (systemd.exec(5)).
ALWAYS = ("execve", "exit", "exit_group", "getrlimit", "rt_sigreturn", "sigreturn")
AF_MAX = 46


def scmp_act_errno(code: int) -> int:
    return 0x00050000 | (code & 0xFFFF)


class ArgCmp(ctypes.Structure):
    _fields_ = [
        ("arg", ctypes.c_uint),
        ("op", ctypes.c_int),
        ("datum_a", ctypes.c_uint64),
        ("datum_b", ctypes.c_uint64),
    ]


@cache
def expand(name: str) -> frozenset[str]:
    """System calls of a name or ``@group`` (recursively), as systemd defines them."""
    if not name.startswith("@"):
        return frozenset([name])
    out = subprocess.run(
        ["systemd-analyze", "syscall-filter", name], capture_output=True, text=True, check=True
    ).stdout
    calls: set[str] = set()
    for line in out.splitlines()[1:]:
        item = line.strip()
        if item and not item.startswith("#"):
            calls |= expand(item)
    return frozenset(calls)


def unit_settings(unit: Path) -> tuple[set[str], int, set[int] | None]:
    """(allowed system calls, errno for the rest, allowed address families or None)."""
    allowed: set[str] | None = None
    error = errno.EPERM
    families: set[int] | None = None
    for raw in unit.read_text().splitlines():
        m = re.match(r"^(SystemCallFilter|SystemCallErrorNumber|RestrictAddressFamilies)=(.*)$",
                     raw.strip())  # fmt: skip
        if not m:
            continue
        key, value = m.groups()
        if key == "SystemCallErrorNumber":
            error = getattr(errno, value.strip())
        elif key == "RestrictAddressFamilies":
            families = {int(getattr(socket, f)) for f in value.split()}
        elif value.startswith("~"):
            assert allowed is not None, "a deny list before the allow list is not emulated"
            for item in value[1:].split():
                allowed -= expand(item)
        else:
            allowed = set(allowed or ()) | {c for item in value.split() for c in expand(item)}
    assert allowed is not None, f"{unit}: no SystemCallFilter= allow list"
    return allowed | set(ALWAYS), error, families


def load_filter(allowed: set[str], error: int, families: set[int] | None) -> None:
    lib = ctypes.CDLL(ctypes.util.find_library("seccomp") or "libseccomp.so.2", use_errno=True)
    lib.seccomp_init.restype = ctypes.c_void_p
    lib.seccomp_init.argtypes = [ctypes.c_uint32]
    lib.seccomp_syscall_resolve_name.argtypes = [ctypes.c_char_p]
    lib.seccomp_rule_add_array.argtypes = [
        ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_uint, ctypes.POINTER(ArgCmp),
    ]  # fmt: skip
    lib.seccomp_load.argtypes = [ctypes.c_void_p]
    ctx = lib.seccomp_init(scmp_act_errno(error))
    socket_nr = lib.seccomp_syscall_resolve_name(b"socket")
    for name in sorted(allowed):
        nr = lib.seccomp_syscall_resolve_name(name.encode())
        if nr < 0 or (nr == socket_nr and families is not None):
            continue  # not a system call of this architecture; socket() is ruled below
        rc = lib.seccomp_rule_add_array(ctx, SCMP_ACT_ALLOW, nr, 0, None)
        assert rc == 0, (name, rc)
    if families is not None and "socket" in allowed:
        for family in range(AF_MAX):
            action = SCMP_ACT_ALLOW if family in families else scmp_act_errno(errno.EAFNOSUPPORT)
            cmp = ArgCmp(0, SCMP_CMP_EQ, family, 0)
            rc = lib.seccomp_rule_add_array(ctx, action, socket_nr, 1, ctypes.byref(cmp))
            assert rc == 0, ("socket", family, rc)
    rc = lib.seccomp_load(ctx)
    assert rc == 0, f"seccomp_load: {rc}"


def main(argv: list[str]) -> int:
    unit, sep, *program = argv
    assert sep == "--" and program, __doc__
    load_filter(*unit_settings(Path(unit)))
    os.execvp(program[0], program)
    return 127  # pragma: no cover


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
