"""A fleet as the README sets it up (config/fleet/): a router, three daemons of two drives
and one subscriber, each in its own process, with mutual TLS and access control."""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest

from observer.cli import main as cli_main
from observer.commands.subscribe import FleetTable, format_line, quality
from observer.config import ZenohFileConfig, load_config
from tests.peers import REPO, free_port
from tests.pki import OPENSSL, make_certs

FLEET = REPO / "config" / "fleet"
DEMO = REPO / "replay" / "data" / "demo.mcap"
DAEMONS = ("shovel1-hoist", "shovel1-crowd", "shovel2-hoist")


def fleet_copy(tmp_path):
    """config/fleet/ in a temporary folder, on a free port, with its certificates made by
    config/fleet/make-certs.sh as the README says."""
    if OPENSSL is None:
        pytest.skip("needs the openssl command")
    folder = tmp_path / "fleet"
    folder.mkdir()
    endpoint = f"127.0.0.1:{free_port()}"
    for config in FLEET.glob("*.toml"):
        text = config.read_text().replace("127.0.0.1:7447", endpoint)
        (folder / config.name).write_text(text.replace("../../replay/data/demo.mcap", str(DEMO)))
    make_certs(folder / "certs", "ca", "router", "shovel1", "shovel2", "control-room")
    return folder


def latest_table(lines):
    """The rows of the last complete table the subscriber drew (stdout, not a terminal)."""
    text = "".join(lines)
    tables = [t for t in text.split("\n\n") if t.startswith("drive ") and t.rstrip().endswith(")")]
    return tables[-1].splitlines()[1:-1] if tables else []


def test_a_router_with_three_daemons_and_one_subscriber_shows_every_motor(tmp_path, children):
    fleet = fleet_copy(tmp_path)
    router = children(["router", "--config", str(fleet / "router.toml")])
    router.wait_line("listening on", timeout=60)
    subscriber = children(
        ["subscribe", "dcobserver/**", "--config", str(fleet / "control-room.toml"),
         "--mode", "client", "--view", "table", "--refresh", "0.5", "--timeout", "300"],
    )  # fmt: skip
    subscriber.wait_line("subscribed to dcobserver/\\*\\* via tls/", timeout=60)
    daemons = [
        children(["run", "--config", str(fleet / f"{name}.toml"), "--quiet-estimates"])
        for name in DAEMONS
    ]
    for daemon in daemons:
        daemon.wait_line(r"zenoh: publishing on dcobserver/shovel\d/", timeout=120)

    expected = {tuple(name.split("-")) for name in DAEMONS}
    number = r"\d[\d.e+-]*"
    # Each row: drive, motor, Rf, Lf, Ra, La, K (each a value with its unit, perhaps a quality
    # mark, and its relative std; or "-"), Tf, Ta, EMF and measured speed, quality, age,
    # health. Wait until every motor's row has a field and armature fit and its health
    # ('dcobserver/**' carries both).
    fit = rf"(-?{number}) (\S+)(?: [-hco?])?\s+{number}"  # value, unit, mark, relative std
    maybe = rf"(?:-?{number} \S+(?: [-hco?])?\s+{number}|-)"
    row = re.compile(
        rf"^(\S+)\s+(\S+)\s+{fit}\s+{maybe}\s+{fit}\s+{maybe}\s+{fit}\s+"
        rf"(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\w+)\s+({number})\s+(.+)$"
    )
    deadline = time.monotonic() + 180
    while True:
        rows = {}
        for line in latest_table(subscriber.stdout):
            m = row.match(line)
            if m and m.group(15).strip() != "-":  # its health (every 1 s) has arrived too
                rows[(m.group(1), m.group(2))] = m
        if set(rows) == expected:
            break
        assert time.monotonic() < deadline, "".join(subscriber.stdout[-12:])
        for daemon in daemons:
            assert daemon.proc.poll() is None, "".join(daemon.stderr[-10:])
        try:
            subscriber.lines.get(timeout=1.0)
        except Exception:
            pass
    for (drive, motor), m in rows.items():
        assert (m.group(4), m.group(6), m.group(8)) == ("ohm", "ohm", "H"), m.group(0)
        rf, ra, k = float(m.group(3)), float(m.group(5)), float(m.group(7))
        # The demo is the P-12: Rf = 185 ohm, Ra = 3.5 ohm, K = 1.12 H.
        assert 150 < rf < 220 and 2.5 < ra < 4.5 and 0.9 < k < 1.4, (drive, motor, m.group(0))
        assert float(m.group(14)) < 10.0, m.group(0)  # age (s): live, not a stale row


def test_the_shipped_fleet_configs_load_strictly(tmp_path):
    fleet = fleet_copy(tmp_path)
    router = load_config(fleet / "router.toml", ZenohFileConfig).zenoh
    assert router.access.enabled and router.access.subscribers == ["control-room"]
    assert set(router.access.publishers) == {"shovel1", "shovel2"}
    assert load_config(fleet / "control-room.toml", ZenohFileConfig).zenoh.tls.enabled
    for name in DAEMONS:
        config = load_config(fleet / f"{name}.toml")
        assert (config.observer.drive_id, config.observer.motor_id) == tuple(name.split("-"))
        assert config.zenoh.mode == "client" and config.zenoh.tls.mutual
        # Each daemon's identity is one the router lets publish its drive's keys.
        cn = Path(config.zenoh.tls.certificate).stem
        assert cn in router.access.publishers[config.observer.drive_id]


def test_the_table_keeps_one_row_per_motor_with_its_latest_estimate_and_health():
    table = FleetTable()
    estimate = {
        "drive_id": "shovel1", "motor_id": "hoist", "t_ns": 5_000_000_000,
        "field": {"R": 185.04, "L": 50.1, "std": {"R": 0.037, "L": None},
                  "quality": {"R": "ok", "L": "held"}},
        "temperature": {"field": {"C": 61.27, "std": 0.4}},
        "armature": {"R": 3.5012, "L": None, "K": 1.1213,
                     "quality": {"R": "ok", "L": "none", "K": "ok"}},
    }  # fmt: skip
    table.update("dcobserver/shovel1/hoist/estimate", estimate, now=100.0)
    table.update("dcobserver/shovel1/hoist/health", {"flags": ["source_stalled"]}, now=100.5)
    table.update("dcobserver/shovel2/event", {"message": "Ra +3.1 % at 12.40 s"}, now=100.7)
    # A drive with one motor (no motor_id) and no estimate yet: health only.
    table.update("dcobserver/shovel2/health", {"drive_id": "shovel2", "flags": []}, now=101.0)
    header, hoist, shovel2, legend = table.render(now=102.0)
    assert header.split()[:2] == ["drive", "motor"] and "age" in header
    cells = hoist.split()
    assert cells[:2] == ["shovel1", "hoist"]
    # Engineering units in every cell, the quality mark after the unit, then the relative
    # std (%) where the estimate has one.
    assert "185.04 ohm    0.02" in hoist and "50.1 H h" in hoist and "3.5012 ohm" in hoist
    assert "1.1213 H" in hoist and header.count("±%") == 5
    assert "61.3" in cells  # the field winding's temperature, when the estimate has one
    assert cells[-3:] == ["none", "2.0", "source_stalled"]  # worst quality, age (s), health
    assert shovel2.split()[:2] == ["shovel2", "-"]
    assert shovel2.endswith("  ok; last event: Ra +3.1 % at 12.40 s")
    assert "held" in legend and "EMF constant per field ampere" in legend
    assert quality({"field": {"R": 1.0, "quality": {"R": "ok"}}}) == "ok"
    assert format_line("dcobserver/shovel2/health", {"flags": []}).split()[-2:] == ["health:", "ok"]


def test_a_bad_certificate_path_is_one_line_naming_key_and_file(tmp_path, capsys):
    config = tmp_path / "router.toml"
    config.write_text('[zenoh]\nlisten = ["tls/127.0.0.1:7447"]\n[zenoh.tls]\nroot_ca = "ca.pem"\n')
    for argv in (["router", "--config", str(config)], ["subscribe", "--config", str(config)]):
        assert cli_main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert str(config) in err and "zenoh.tls.root_ca" in err and str(tmp_path / "ca.pem") in err
