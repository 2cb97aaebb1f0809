"""The import rule: the house's packages import one way (docs/architecture.md).

Every ``import`` and ``from ... import`` of every module of ``observer/``,
``drivers/`` and ``replay/`` is read from its syntax tree -- imports inside
functions and ``TYPE_CHECKING`` blocks included -- and each first-party target
must be allowed for the importing package:

==========================  ====================================================
package                     may import (besides itself)
==========================  ====================================================
observer.config             nothing of the project
observer.estimation         observer.config
observer.recording          observer.config
observer.simulation         observer.estimation, observer.recording, observer.config
observer.diagnosis          observer.estimation, observer.recording, observer.config
observer.service            observer.estimation, observer.recording, observer.config, drivers
drivers                     observer.config
replay                      drivers, observer.recording, observer.config
observer.cli, .commands     anything (the CLI is the top; nothing else imports it)
==========================  ====================================================

Modules named by string (the CLI's command table, the drivers' registry of
sources) are looked up by name at run time and are not imports.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FIRST_PARTY = ("observer", "drivers", "replay")

#: package -> what else its modules may import. The longest matching package wins.
RULES: dict[str, tuple[str, ...]] = {
    "observer": (),  # observer/__init__.py: the version only
    "observer.config": (),
    "observer.estimation": ("observer.config",),
    "observer.recording": ("observer.config",),
    "observer.simulation": ("observer.estimation", "observer.recording", "observer.config"),
    "observer.diagnosis": ("observer.estimation", "observer.recording", "observer.config"),
    "observer.service": (
        "observer.estimation",
        "observer.recording",
        "observer.config",
        "drivers",
    ),  # fmt: skip
    "drivers": ("observer.config",),
    "replay": ("drivers", "observer.recording", "observer.config"),
    "observer.cli": ("*",),
    "observer.commands": ("*",),
}

#: observer/ at its top: the entry points everything may reach, and the subpackages.
TOP_MODULES = {"__init__.py", "cli.py", "config.py"}
SUBPACKAGES = {"commands", "estimation", "recording", "simulation", "diagnosis", "service"}


@dataclass(frozen=True)
class Import:
    importer: str
    target: str
    path: Path
    line: int


def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_module(name: str, root: Path) -> bool:
    base = root.joinpath(*name.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def imports_of(path: Path, root: Path = REPO) -> list[Import]:
    """First-party modules ``path`` imports, wherever in the file the import stands."""
    importer = _module_name(path, root)
    package = importer if path.name == "__init__.py" else importer.rpartition(".")[0]
    found: list[Import] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            for alias in node.names:
                # `from a import b` imports module a.b when there is one, else a name of a.
                sub = f"{base}.{alias.name}"
                targets.append(sub if _is_module(sub, root) else base)
        for target in targets:
            if target.split(".")[0] in FIRST_PARTY:
                found.append(Import(importer, target, path, node.lineno))
    return found


def _within(name: str, package: str) -> bool:
    return name == package or name.startswith(package + ".")


def rule_of(module: str) -> str:
    """The package whose rule applies to ``module`` (the longest that contains it)."""
    matches = [p for p in RULES if _within(module, p)]
    if not matches:
        raise LookupError(f"{module} belongs to no package of the import rule")
    return max(matches, key=len)


def violations(root: Path = REPO) -> list[str]:
    out = []
    for top in FIRST_PARTY:
        for path in sorted((root / top).rglob("*.py")):
            for imp in imports_of(path, root):
                package = rule_of(imp.importer)
                allowed = RULES[package]
                # A package may import itself; observer's own __init__ holds only the version.
                itself = (
                    imp.target == package if package == "observer" else _within(imp.target, package)
                )
                if "*" in allowed or itself:
                    continue
                if not any(_within(imp.target, a) for a in allowed):
                    where = f"{imp.path.relative_to(root)}:{imp.line}"
                    out.append(
                        f"{where}: {imp.importer} imports {imp.target}; "
                        f"{package} may import only {', '.join(allowed) or 'itself'}"
                    )
    return out


def test_every_import_follows_the_rule():
    assert violations() == []


def test_a_broken_rule_is_caught(tmp_path):
    """The checker itself: a copy of the packages with one forbidden import in a function."""
    for top in FIRST_PARTY:
        for path in (REPO / top).rglob("*.py"):
            copy = tmp_path / path.relative_to(REPO)
            copy.parent.mkdir(parents=True, exist_ok=True)
            copy.write_text(path.read_text())
    kernels = tmp_path / "observer" / "estimation" / "kernels.py"
    kernels.write_text(
        kernels.read_text()
        + "\n\ndef _peek():\n    from observer.service import daemon\n\n    return daemon\n"
    )
    relative = tmp_path / "observer" / "recording" / "base.py"
    relative.write_text(relative.read_text() + "\nfrom ..simulation.simulate import simulate\n")
    found = violations(tmp_path)
    assert len(found) == 2, found
    assert "observer.estimation.kernels imports observer.service.daemon" in found[0] + found[1]
    assert "observer.recording.base imports observer.simulation.simulate" in found[0] + found[1]


def test_observer_keeps_only_its_entry_points_at_the_top():
    top = {p.name for p in (REPO / "observer").glob("*.py")}
    assert top <= TOP_MODULES, f"move {sorted(top - TOP_MODULES)} into a subpackage"
    packages = {p.parent.name for p in (REPO / "observer").glob("*/__init__.py")}
    assert packages == SUBPACKAGES, "a new subpackage needs its import rule here first"


@pytest.mark.parametrize("package", sorted(SUBPACKAGES - {"commands"}))
def test_each_subpackage_states_its_rule_and_where_to_start(package):
    doc = ast.get_docstring(ast.parse((REPO / "observer" / package / "__init__.py").read_text()))
    assert doc and "Import rule" in doc and "Start with" in doc
