"""Zenoh security against real peers: a router and parties in other processes on loopback.

Zenoh drops what access control denies without an error, so every test asserts
non-delivery *and*, in the same run, delivery to the allowed party: a test that
received nothing at all cannot pass.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest

from observer.config import AccessConfig, TlsConfig, ZenohLinkConfig
from observer.service.zenohconf import access_control, key, parse_key, session_config
from tests.peers import free_port

PARTY = Path(__file__).with_name("zenoh_party.py")


def _toml_value(value):
    return json.dumps(value) if not isinstance(value, bool) else str(value).lower()


def zenoh_file(path, *, listen=(), connect=(), tls=None, auth=None, access=None):
    """A file with a ``[zenoh]`` table (what ``router`` and ``subscribe --config`` read)."""
    lines = [
        "[zenoh]",
        f"listen = {json.dumps(list(listen))}",
        f"connect = {json.dumps(list(connect))}",
    ]
    for name, table in (("tls", tls), ("auth", auth), ("access", access)):
        if not table:
            continue
        lines.append(f"[zenoh.{name}]")
        nested = {k: v for k, v in table.items() if isinstance(v, dict)}
        lines += [f"{k} = {_toml_value(v)}" for k, v in table.items() if k not in nested]
        for k, v in nested.items():
            lines.append(f"[zenoh.{name}.{k}]")
            lines += [f'"{kk}" = {_toml_value(vv)}' for kk, vv in v.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def tls_of(pki, cert=None, *, mutual=True):
    table = {"root_ca": str(pki.root_ca), "mutual": mutual}
    if cert is not None:
        table |= {"certificate": str(cert.certificate), "private_key": str(cert.private_key)}
    return table


def count(child, pattern):
    regex = re.compile(pattern)
    return sum(1 for line in list(child.stdout) if regex.search(line))


def wait_count(child, pattern, n, timeout=60.0):
    """Wait (on the child's output, not on a clock) until ``n`` lines match ``pattern``."""
    deadline = time.monotonic() + timeout
    while count(child, pattern) < n:
        if time.monotonic() > deadline or child.proc.poll() is not None:
            raise AssertionError(
                f"{count(child, pattern)} of {n} lines matching {pattern!r}; "
                f"stdout tail {child.stdout[-5:]}, stderr tail {child.stderr[-5:]}"
            )
        try:
            child.lines.get(timeout=0.2)
        except Exception:
            pass


class Network:
    """Parties of one test, each in its own process, each with its own config file."""

    def __init__(self, tmp_path, children, endpoint):
        self.tmp_path = tmp_path
        self.children = children
        self.endpoint = endpoint

    def party(self, name, *, mode="client", sub=None, put=(), **security):
        config = zenoh_file(self.tmp_path / f"{name}.toml", connect=[self.endpoint], **security)
        args = [str(config), mode, *(["--sub", sub] if sub else [])]
        for spec in put:
            args += ["--put", spec]
        child = self.children(args, script=PARTY)
        line = child.wait_line(r"^(open|refused)", stream="out", timeout=60)
        assert line.startswith("open"), (name, line)
        if sub:
            child.wait_line("^declared", stream="out", timeout=60)
        return child


def assert_nothing_forged(received_by, attackers):
    got = "".join(received_by.stdout)
    assert "forged" not in got, [x for x in received_by.stdout if "forged" in x][:5]
    for name, attacker in attackers.items():
        assert attacker.proc.poll() is None, f"{name} ended: {attacker.stdout[-3:]}"
        assert count(attacker, r"^got ") == 0, (name, attacker.stdout[-3:])


def test_mutual_tls_router_lets_only_the_drive_publish_and_only_listed_clients_read(
    tmp_path, pki, children
):
    endpoint = f"tls/127.0.0.1:{free_port()}"
    access = {
        "enabled": True,
        "subscribers": ["control-room", "protection"],
        "publishers": {"drive1": ["drive1"], "drive2": ["drive2"]},
    }
    router_toml = zenoh_file(
        tmp_path / "router.toml", listen=[endpoint],
        tls=tls_of(pki, pki.certificate("router")), access=access,
    )  # fmt: skip
    router = children(["router", "--config", str(router_toml)])
    router.wait_line("listening on", timeout=60)
    net = Network(tmp_path, children, endpoint)
    everything, drive1_key = "dcobserver/**", key("drive1", "estimate")

    control = net.party(
        "control-room", sub=everything, tls=tls_of(pki, pki.certificate("control-room"))
    )
    attackers = {
        # Another listed subscriber: reading is all it may do, it cannot publish.
        "subscriber": net.party(
            "protection", put=[f"{drive1_key}=forged-by-subscriber"],
            tls=tls_of(pki, pki.certificate("protection")),
        ),
        # A certificate from our CA with a name nobody listed.
        "unlisted": net.party(
            "intruder", sub=everything, put=[f"{drive1_key}=forged-by-unlisted"],
            tls=tls_of(pki, pki.certificate("intruder")),
        ),
        # Another drive's observer: its own keys yes, drive1's no.
        "drive2": net.party(
            "drive2", sub=everything,
            put=[f"{key('drive2', 'estimate')}=drive2", f"{drive1_key}=forged-by-drive2"],
            tls=tls_of(pki, pki.certificate("drive2")),
        ),
        # No certificate at all, and drive1's own name from another CA: the TLS handshake
        # fails; as peers their sessions open and keep trying all through the test.
        "no certificate": net.party(
            "nocert", mode="peer", sub=everything, put=[f"{drive1_key}=forged-by-nocert"],
            tls=tls_of(pki, mutual=False),
        ),
        "other CA": net.party(
            "otherca", mode="peer", sub=everything, put=[f"{drive1_key}=forged-by-other-ca"],
            tls=tls_of(pki, pki.certificate("drive1", ca="other")),
        ),
    }  # fmt: skip
    for attacker in attackers.values():
        wait_count(attacker, r"^put ", 3)  # each has been putting for >= 20 ms
    net.party("drive1", put=[f"{drive1_key}=legit"], tls=tls_of(pki, pki.certificate("drive1")))

    wait_count(control, r"^got dcobserver/drive1/estimate legit ", 50)
    wait_count(control, r"^got dcobserver/drive2/estimate drive2 ", 50)
    for attacker in attackers.values():
        assert count(attacker, r"^put ") >= 5  # all along: 50 rounds of theirs reached nobody
    assert_nothing_forged(control, attackers)
    # drive2 is a publisher, not a listed subscriber: it read nothing either (checked above).

    # As clients, the parties without a valid certificate are refused at once.
    for name, tls in (
        ("no certificate", tls_of(pki, mutual=False)),
        ("other CA", tls_of(pki, pki.certificate("control-room", ca="other"))),
    ):
        config = zenoh_file(tmp_path / "refused.toml", connect=[endpoint], tls=tls)
        sub = children(["subscribe", "--config", str(config), "--mode", "client"])
        assert sub.proc.wait(60) == 2, name
        err = "".join(sub.stderr).strip()
        assert len(err.splitlines()) == 1 and "cannot open a Zenoh session" in err, (name, err)


def test_user_password_router_refuses_wrong_passwords_and_grants_by_user_name(tmp_path, children):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    passwords = {"drive1": "s3cret-d", "control-room": "s3cret-c", "guest": "s3cret-g"}
    users = tmp_path / "users.txt"
    users.write_text("".join(f"{user}:{pw}\n" for user, pw in passwords.items()))
    for name, password in {**passwords, "wrong": "not-the-secret"}.items():
        (tmp_path / f"{name}.password").write_text(password + "\n")
    access = {
        "enabled": True, "identify_by": "username",
        "subscribers": ["control-room"], "publishers": {"drive1": ["drive1"]},
    }  # fmt: skip
    router_toml = zenoh_file(
        tmp_path / "router.toml", listen=[endpoint],
        auth={"dictionary_file": str(users)}, access=access,
    )  # fmt: skip
    router = children(["router", "--config", str(router_toml)])
    router.wait_line("listening on", timeout=60)
    net = Network(tmp_path, children, endpoint)

    def auth(user, password=None):
        return {"user": user, "password_file": str(tmp_path / f"{password or user}.password")}

    everything, drive1_key = "dcobserver/**", key("drive1", "estimate")
    control = net.party("control-room", sub=everything, auth=auth("control-room"))
    guest = net.party(
        "guest", sub=everything, put=[f"{drive1_key}=forged-by-guest"], auth=auth("guest")
    )
    wait_count(guest, r"^put ", 3)
    net.party("drive1", put=[f"{drive1_key}=legit"], auth=auth("drive1"))
    wait_count(control, r"^got dcobserver/drive1/estimate legit ", 50)
    assert_nothing_forged(control, {"guest (a user nobody listed)": guest})

    for name, security in (
        ("wrong password", {"auth": auth("control-room", "wrong")}),
        ("no user", {}),
    ):
        config = zenoh_file(tmp_path / "refused.toml", connect=[endpoint], **security)
        sub = children(["subscribe", "--config", str(config), "--mode", "client"])
        assert sub.proc.wait(60) == 2, name
        assert "cannot open a Zenoh session" in "".join(sub.stderr), name


def test_a_daemon_peer_without_router_serves_only_listed_subscribers(tmp_path, pki, children):
    """The drive PC's own session (peer mode, subscribers connect to it) enforces access too."""
    endpoint = f"tls/127.0.0.1:{free_port()}"
    drive_toml = zenoh_file(
        tmp_path / "drive1.toml", listen=[endpoint],
        tls=tls_of(pki, pki.certificate("drive1")),
        access={"enabled": True, "subscribers": ["control-room"]},
    )  # fmt: skip
    drive = children([str(drive_toml), "peer", "--put", "dcobserver/drive1/estimate=legit"],
                     script=PARTY)  # fmt: skip
    drive.wait_line("^open", stream="out", timeout=60)
    net = Network(tmp_path, children, endpoint)
    intruder = net.party(
        "intruder", sub="dcobserver/**", put=["dcobserver/drive1/estimate=forged-by-unlisted"],
        tls=tls_of(pki, pki.certificate("intruder")),
    )  # fmt: skip
    control = net.party(
        "control-room", sub="dcobserver/**", tls=tls_of(pki, pki.certificate("control-room"))
    )
    wait_count(control, r"^got dcobserver/drive1/estimate legit ", 50)
    assert_nothing_forged(control, {"unlisted": intruder})


# ------------------------------------------------------------------ the generated settings


def test_keys_with_and_without_a_motor():
    assert key("shovel7", "estimate") == "dcobserver/shovel7/estimate"
    assert key("shovel7", "estimate", "hoist1") == "dcobserver/shovel7/hoist1/estimate"
    assert parse_key("dcobserver/shovel7/hoist1/estimate") == ("shovel7", "hoist1", "estimate")
    assert parse_key("dcobserver/shovel7/health") == ("shovel7", "", "health")


def test_access_rules_grant_per_drive_and_deny_the_rest():
    acl = access_control(
        AccessConfig(
            enabled=True,
            publishers={"d1": ["obs-a", "obs-b"], "d2": ["obs-a"]},
            subscribers=["control"],
        )
    )
    assert acl["default_permission"] == "deny"
    subjects = {s["id"]: s for s in acl["subjects"]}
    assert sorted(s["cert_common_names"][0] for s in subjects.values()) == [
        "control", "obs-a", "obs-b",
    ]  # fmt: skip
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["publish d1"]["key_exprs"] == ["dcobserver/d1/**"]
    assert rules["publish d1"]["flows"] == ["ingress"] and "put" in rules["publish d1"]["messages"]
    granted = {
        rule: sorted(subjects[s]["cert_common_names"][0] for s in p["subjects"])
        for p in acl["policies"]
        for rule in p["rules"]
    }
    assert granted["publish d2"] == ["obs-a"]
    assert granted["subscribe"] == ["control"] and granted["deliver"] == ["control"]
    assert "put" not in rules["subscribe"]["messages"]


def test_tls_settings_reach_zenoh(pki):
    cert = pki.certificate("drive1")
    link = ZenohLinkConfig(
        connect=["tls/127.0.0.1:7447"],
        tls=TlsConfig(str(pki.root_ca), str(cert.certificate), str(cert.private_key)),
    )
    tls = session_config(link, "client")["transport"]["link"]["tls"]
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert tls["connect_certificate"] == str(cert.certificate)
    assert tls["root_ca_certificate"] == str(pki.root_ca)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"connect": ["tls/127.0.0.1:1"]}, "needs [zenoh.tls]"),
        ({"connect": ["127.0.0.1:7447"]}, "is not an endpoint"),
        ({"access": AccessConfig(enabled=True)}, "needs mutual TLS"),
        ({"access": AccessConfig(enabled=True, identify_by="username")}, "dictionary_file"),
    ],
)
def test_inconsistent_security_is_refused(settings, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        ZenohLinkConfig(**settings)


def test_a_drive_not_granted_sees_no_subscriber_in_its_health(tmp_path, pki, children):
    """A wrong grant is silent on the wire; the daemon's own health shows it."""
    from observer.config import ZenohConfig
    from observer.service.zenohpub import ZenohPublisher

    endpoint = f"tls/127.0.0.1:{free_port()}"
    access = {
        "enabled": True,
        "subscribers": ["control-room"],
        "publishers": {"drive1": ["drive1"]},
    }
    router_toml = zenoh_file(
        tmp_path / "router.toml", listen=[endpoint],
        tls=tls_of(pki, pki.certificate("router")), access=access,
    )  # fmt: skip
    children(["router", "--config", str(router_toml)]).wait_line("listening on", timeout=60)
    Network(tmp_path, children, endpoint).party(
        "control-room", sub="dcobserver/**", tls=tls_of(pki, pki.certificate("control-room"))
    )

    def publisher(drive):
        cert = pki.certificate(drive)
        tls = TlsConfig(str(pki.root_ca), str(cert.certificate), str(cert.private_key))
        config = ZenohConfig(mode="client", listen=[], connect=[endpoint], tls=tls)
        return ZenohPublisher(config, drive)

    granted, ungranted = publisher("drive1"), publisher("drive9")
    try:
        granted.start()
        ungranted.start()
        assert granted.wait_for_subscriber(60)
        assert not ungranted.wait_for_subscriber(2.0)
        assert granted.health()["subscriber_matched"] is True
        health = ungranted.health()
        assert health["state"] == "open" and health["subscriber_matched"] is False
    finally:
        granted.close()
        ungranted.close()
