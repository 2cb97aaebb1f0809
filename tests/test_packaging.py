"""What a plain ``pip install -e .`` (the README's first command) must bring."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_the_runtime_dependencies_include_what_the_compiled_kernels_call():
    """numba compiles ``a @ b`` on arrays to BLAS calls it finds through scipy; the jump fits
    (observer/estimation/filter_id.py, dealias.py) use it, so the daemon's first kernel failed
    without scipy on an install without the test extras."""
    project = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    names = {re.split(r"[<>=!~\[ ;]", d, maxsplit=1)[0].lower() for d in project["dependencies"]}
    assert {"numpy", "numba", "scipy"} <= names
    kernels = (REPO / "observer" / "estimation" / "filter_id.py").read_text(encoding="utf-8")
    assert " @ " in kernels  # the day it is not, this test can go with the dependency
