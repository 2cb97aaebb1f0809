"""The shipped config/<adapter>-sim.toml files build their sources (strict config, real files)."""

from __future__ import annotations

import tomllib

import pytest

from drivers import source_class
from tests.drivers.peers import REPO


@pytest.mark.parametrize("name", ["serial", "modbus", "can"])
def test_sim_config_builds_its_source(name):
    path = REPO / "config" / f"{name}-sim.toml"
    with path.open("rb") as fh:
        table = tomllib.load(fh)["source"]
    assert table["kind"] == name
    src = source_class(name).from_config(table["options"], source=str(path), base_dir=path.parent)
    try:
        assert src.name == name
        if name == "can":
            assert src.options.dbc == str(REPO / "config" / "p12.dbc")
        if name == "modbus":
            assert [r.channel for r in src.options.registers][-1] == "omega"
    finally:
        src.close()
