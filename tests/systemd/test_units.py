"""The systemd units: they verify, score <= 2.0 in ``systemd-analyze security``, and the
daemon still runs its adapters under their system-call filter and address families."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.drivers.peers import FakeDrive
from tests.peers import REPO, free_port

SANDBOX = Path(__file__).with_name("sandbox.py")
UNITS = REPO / "systemd"
#: The exposure issue 13 asks for at most (the units score 1.7 on systemd 252).
MAX_EXPOSURE = 2.0

needs_systemd_analyze = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None, reason="needs systemd-analyze"
)


def installed(tmp_path, name, instance=None):
    """A copy of ``systemd/<name>`` whose ExecStart is this interpreter's console script
    (``verify`` wants the binary to exist), under the instance's name for a template."""
    exe = Path(sys.executable).with_name("dcobserver")
    assert exe.exists()
    text = re.sub(r"ExecStart=\S+", f"ExecStart={exe}", (UNITS / name).read_text())
    copy = tmp_path / (name.replace("@", f"@{instance}") if instance else name)
    copy.write_text(text)
    return copy


def analyze(*args):
    result = subprocess.run(
        ["systemd-analyze", *args], capture_output=True, text=True, timeout=120
    )  # fmt: skip
    return result.returncode, (result.stdout + result.stderr).strip()


UNIT_FILES = [("dcobserver.service", None), ("dcobserver@.service", "hoist1")]


@needs_systemd_analyze
@pytest.mark.parametrize(("name", "instance"), UNIT_FILES)
def test_units_verify_cleanly(tmp_path, name, instance):
    unit = installed(tmp_path, name, instance)
    rc, output = analyze("verify", str(unit))
    # Unknown keys only warn: any output at all is a failure.
    assert rc == 0 and output == "", output
    text = unit.read_text()
    for key in ("Type=notify", "WatchdogSec=", "Restart=on-failure", "NUMBA_CACHE_DIR="):
        assert key in text


@needs_systemd_analyze
@pytest.mark.parametrize(("name", "instance"), UNIT_FILES)
def test_exposure_is_at_most_2(tmp_path, name, instance):
    unit = installed(tmp_path, name, instance)
    rc, output = analyze("security", "--offline=true", str(unit))
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", output)
    assert m, output[-500:]
    assert float(m.group(1)) <= MAX_EXPOSURE, output
    # What the README and the units' comments say is what systemd measures.
    assert f"exposure {m.group(1)}" in (UNITS / name).read_text()


def test_the_template_differs_only_by_the_instance():
    """Same settings but the per-instance paths: no hardening can drift between the two."""

    def settings(name):
        lines = (UNITS / name).read_text().split("[Unit]", 1)[1].splitlines()
        return [x for x in lines if x and not x.startswith("#")]

    single, template = settings("dcobserver.service"), settings("dcobserver@.service")
    assert len(single) == len(template)
    differ = [(a, b) for a, b in zip(single, template, strict=True) if a != b]
    assert differ and all("%i" in b and "%i" not in a for a, b in differ), differ
    assert "ExecStart=/opt/dcobserver/bin/dcobserver run --config /etc/dcobserver/%i.toml" in (
        template
    )


needs_seccomp = pytest.mark.skipif(
    shutil.which("systemd-analyze") is None
    or not any(Path(p).exists() for p in ("/usr/lib/x86_64-linux-gnu/libseccomp.so.2",
                                           "/lib/x86_64-linux-gnu/libseccomp.so.2")),
    reason="needs systemd-analyze and libseccomp (x86-64)",
)  # fmt: skip


@needs_seccomp
def test_the_sandbox_denies_what_the_unit_denies(children):
    """The emulated filter is live: a privileged call and an exotic socket are refused."""
    probe = (
        "import os, socket\n"
        "try:\n    os.setuid(0); print('setuid allowed')\n"
        "except OSError as e:\n    print('setuid', e.errno)\n"
        "try:\n    socket.socket(socket.AF_PACKET, socket.SOCK_RAW); print('packet allowed')\n"
        "except OSError as e:\n    print('packet', e.errno)\n"
        "socket.socket(socket.AF_INET, socket.SOCK_STREAM).close(); print('inet ok')\n"
    )
    result = subprocess.run(
        [sys.executable, str(SANDBOX), str(UNITS / "dcobserver.service"), "--",
         sys.executable, "-c", probe],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.stdout.split("\n")[:3] == ["setuid 1", "packet 97", "inet ok"], result


@needs_seccomp
@pytest.mark.slow
def test_the_daemon_runs_its_serial_adapter_and_zenoh_under_the_units_filter(tmp_path, children):
    """The unit's SystemCallFilter= and RestrictAddressFamilies= emulated with libseccomp:
    a serial fake drive on a pty in, Zenoh out to a subscriber listening on all addresses,
    and the armature's second process (parallel_circuits) started and answering."""
    link = tmp_path / "serial"
    drive = FakeDrive("serial", "--link", str(link))
    try:
        port = free_port()
        serial_sim = (REPO / "config" / "serial-sim.toml").read_text()
        config = tmp_path / "serial.toml"
        config.write_text(
            serial_sim.replace('"/tmp/dcobserver-fake-serial"', json.dumps(str(link)))
            + f'\n[zenoh]\nlisten = ["tcp/0.0.0.0:{port}"]\n'
            + '\n[observer]\nparallel_circuits = "on"\n'
        )
        assert str(link) in config.read_text()
        daemon = children(
            ["run", "--config", str(config)],
            prefix=(sys.executable, str(SANDBOX), str(UNITS / "dcobserver.service"), "--"),
        )  # fmt: skip
        zenoh, worker = "zenoh: publishing on", "field and armature estimated in two processes"
        first = daemon.wait_line(f"{zenoh}|{worker}", timeout=300)
        daemon.wait_line(worker if zenoh in first else zenoh, timeout=300)
        sub = children(
            ["subscribe", "--connect", f"tcp/127.0.0.1:{port}", "--json", "--count", "3",
             "--timeout", "60"],
        )  # fmt: skip
        assert sub.proc.wait(90) == 0, "".join(sub.stderr[-5:])
        estimates = [json.loads(x) for x in sub.stdout if x.startswith("{")]
        assert len(estimates) == 3, sub.stdout
        # Every window fitted the field (its own fit: the tracked value is published only once
        # a window's std passes the quality limit, which behind the fake drive's field bridge
        # may take a few windows).
        assert all(e["field"]["raw"]["R"] is not None for e in estimates), estimates[-1]
        assert daemon.proc.poll() is None, "".join(daemon.stderr[-10:])
        assert not [x for x in daemon.stderr if "circuit worker" in x], daemon.stderr[-10:]
    finally:
        drive.kill()
