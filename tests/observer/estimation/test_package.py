"""observer.estimation's public names: importable from the package, loaded only when used."""

from __future__ import annotations

import importlib
import subprocess
import sys

import observer.estimation as estimation


def test_every_public_name_is_the_object_of_its_module():
    for name in estimation.__all__:
        module = importlib.import_module(f"observer.estimation.{estimation._EXPORTS[name]}")
        assert getattr(estimation, name) is getattr(module, name)


def test_the_cli_parser_reads_the_motor_table_without_loading_numba():
    code = (
        "import sys, observer.cli; observer.cli.build_parser(); "
        "from observer.estimation import MOTORS; assert MOTORS; "
        "sys.exit('numba' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", code], timeout=60).returncode == 0
