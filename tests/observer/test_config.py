"""Strict TOML config: unknown keys and bad values name the key and the file."""

from __future__ import annotations

import pytest

from observer.config import Config, ConfigError, load_config


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
