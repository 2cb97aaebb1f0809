"""Strict TOML config: unknown keys and bad values name the key and the file."""

from __future__ import annotations

import pytest

from observer.config import Config, ConfigError, load_config
from tests.peers import REPO


def write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def test_valid_config_and_defaults(tmp_path):
    cfg = load_config(
        write(
            tmp_path,
            "[estimate]\nparticles = 50\n[estimate.field]\nR = [100.0, 300]\nL = [1, 90.5]\n",
        )
    )
    assert isinstance(cfg, Config)
    assert cfg.estimate.particles == 50
    assert cfg.estimate.iterations == 100
    assert cfg.estimate.field.R == (100.0, 300.0)
    assert cfg.estimate.armature.R is None


@pytest.mark.parametrize(
    ("text", "fragments"),
    [
        ("[estimate]\nparticle = 5\n", ["c.toml", "estimate.particle", "particles"]),
        ("[estimat]\n", ["c.toml", "estimat"]),
        ("[estimate]\nparticles = 1\n", ["c.toml", "estimate.particles", ">= 2"]),
        ("[estimate]\nparticles = 'many'\n", ["estimate.particles", "integer"]),
        ("[estimate]\nschedule = 'ks'\n", ["estimate.schedule", "'s-k'"]),
        ("[estimate.field]\nR = [300.0, 100.0]\n", ["estimate.field.R", "low < high"]),
        ("[estimate.field]\nR = [1.0]\n", ["estimate.field.R", "2 values"]),
        ("[estimate\n", ["c.toml", "TOML"]),
        ('[observer]\nmotor_id = "a/b"\n', ["observer.motor_id", "'/'"]),
        ("[chain.va]\ngain_tolerance = 0.7\n", ["c.toml", "chain.va.gain_tolerance", "[0, 0.5)"]),
        # Zenoh security: a bad path names the key and the file (resolved beside the config).
        (
            '[zenoh.tls]\nroot_ca = "certs/ca.pem"\n',
            ["c.toml", "zenoh.tls.root_ca", "certs/ca.pem"],
        ),
        ('[zenoh.tls]\nroot_ca = "c.toml"\n', ["zenoh.tls.root_ca", "not a PEM file"]),
        ('[zenoh.auth]\nuser = "u"\npassword_file = "pw"\n', ["zenoh.auth.password_file", "pw"]),
        ('[zenoh.auth]\nuser = "u"\n', ["[zenoh.auth]", "password_file"]),
        ('[zenoh]\nconnect = ["tls/10.0.0.1:7447"]\n', ["c.toml", "[zenoh]", "needs [zenoh.tls]"]),
        ("[zenoh.access]\nenabled = true\n", ["c.toml", "needs mutual TLS"]),
        ("[zenoh.access]\nallow = []\n", ["zenoh.access.allow", "subscribers"]),
        ('[zenoh.access.publishers]\n"a/b" = ["x"]\n', ["zenoh.access", "publishers.a/b"]),
    ],
)
def test_bad_config_names_key_and_file(tmp_path, text, fragments):
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    for fragment in fragments:
        assert fragment in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "nope.toml")


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "config").glob("*.toml")))
def test_shipped_configs_load(name):
    """config/*.toml as shipped (config/fleet/ needs certificates: tests/observer/test_fleet.py)."""
    assert isinstance(load_config(REPO / "config" / name), Config)
