"""What the commands show: engineering units, the units of every JSON, and the warnings.

Not a command (it is not in :data:`observer.cli.COMMANDS`). Tables show values
with SI prefixes (``La 20.54 mH``, not ``0.0205 H``); JSON keeps SI base units
and says which in a ``units`` map. Plain ASCII (``ohm``, ``u`` for micro), so
no terminal or pipe can fail to encode it.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

_PREFIXES = {-4: "p", -3: "n", -2: "u", -1: "m", 0: "", 1: "k", 2: "M", 3: "G"}

#: SI unit of each estimated quantity, as named in the estimates' JSON.
UNITS: dict[str, str] = {
    "R": "ohm",
    "L": "H",
    "K": "H",
    "kphi": "V*s/rad",
    "kphi_std": "V*s/rad",
    "tau": "s",
    "rms": "A",
    "i0": "A",
    "if_mean": "A",
    "input_noise_var": "V^2",
    "rel_std": "1",
    "std": "the unit of the parameter",
    "search_range": "R: ohm, L: H",
    "t_ns": "ns",
    "window": "ns",
    "sample_rate_hz": "Hz",
    "elapsed_ms": "ms",
}

#: The ``units`` map of each estimate a command prints as JSON (``replay --json``,
#: ``subscribe --json``): the keys of the daemon's estimates, in SI base units.
ESTIMATE_UNITS: dict[str, str] = {
    k: UNITS[k] for k in ("R", "L", "K", "rms", "rel_std", "std", "t_ns", "window")
}

#: The display name of each parameter of each circuit.
NAMES: dict[tuple[str, str], str] = {
    ("field", "R"): "Rf",
    ("field", "L"): "Lf",
    ("armature", "R"): "Ra",
    ("armature", "L"): "La",
    ("armature", "K"): "K",
}

K_EXPLAINED = (
    "K: EMF constant per field ampere (H = V*s/(rad*A)); kPhi = K*if{at}: the EMF constant "
    "at the present field (V*s/rad), the figure a motor's data sheet gives"
)


def _exponent(value: float) -> int:
    if value == 0 or not math.isfinite(value):
        return 0
    return max(-4, min(3, int(math.floor(math.log10(abs(value)) / 3))))


def prefix_scale(value: float) -> tuple[float, str]:
    """The power of 1000 and its SI prefix that put ``|value|`` in [1, 1000).

    ``prefix_scale(0.0205) == (0.001, "m")``; pico to giga, beyond them the nearest; 0, NaN
    and infinities get ``(1.0, "")``. Tables and figures divide by the factor and write the
    prefix before the unit.
    """
    e = _exponent(value)
    return 1000.0**e, _PREFIXES[e]


def eng(value: float | None, unit: str, digits: int = 4, *, exponent: int | None = None) -> str:
    """``value`` with an SI prefix: ``eng(0.000196436, "H") == "196.4 uH"``.

    Parameters
    ----------
    value : float or None
        None, NaN and infinities print as ``-``, ``nan``, ``inf``.
    unit : str
        The SI unit (``"ohm"``, ``"H"``, ``"A"``, ...).
    digits : int
        Significant digits.
    exponent : int, optional
        Force the prefix (power of 1000), to print a std with its value's prefix.
    """
    if value is None:
        return "-"
    if not math.isfinite(value):
        return f"{value} {unit}"
    e = _exponent(value) if exponent is None else exponent
    scaled = value / 1000.0**e
    text = f"{scaled:.{digits}g}"
    if "e" in text:  # far from the forced prefix: plain scientific notation
        return f"{value:.{digits}g} {unit}"
    return f"{text} {_PREFIXES[e]}{unit}"


def eng_pair(value: float | None, std: float | None, unit: str) -> tuple[str, str]:
    """A value and its std in the same prefix: ``("20.54 mH", "1.02 mH")``."""
    if value is None or not math.isfinite(value):
        return eng(value, unit), eng(std, unit, 3)
    e = _exponent(value)
    if std is None or not math.isfinite(std) or abs(std) < 1000.0**e:
        # Below one unit of the value's prefix: its own prefix reads better (148 uH, not
        # 0.000148 H).
        return eng(value, unit, exponent=e), eng(std, unit, 3)
    return eng(value, unit, exponent=e), eng(std, unit, 3, exponent=e)


def percent(x: float | None, *, signed: bool = False) -> str:
    """A relative quantity in percent: 2-3 significant digits, whole percent above 100 %."""
    if x is None:
        return "-"
    if not math.isfinite(x):
        return "inf"
    sign = "+" if signed else ""
    if abs(x) >= 1:
        return f"{100 * x:{sign}.0f} %"
    return f"{100 * x:{sign}.2g} %" if abs(x) < 0.1 else f"{100 * x:{sign}.3g} %"


def units_hint(suggest: Mapping[str, str], supported: bool) -> str:
    """`` (read it so with --units t=ms)`` for a finding's suggestion, where it applies."""
    if not suggest:
        return ""
    spec = ",".join(f"{column}={unit}" for column, unit in suggest.items())
    if supported:
        return f" (if so: --units {spec})"
    return f" (if so, convert it: dcobserver estimate/diagnose take --units {spec})"


def report_findings(
    command: str,
    findings: Iterable[Any],
    *,
    path: str | None = None,
    units_option: bool = True,
    defer: bool = False,
) -> list[str]:
    """Print the warnings on stderr and raise the first error; returns the warning lines.

    Parameters
    ----------
    command : str
        The command's name, for the message prefix.
    findings : iterable of observer.estimation.plausibility.Finding
    path : str, optional
        The recording, named in front of each message.
    units_option : bool
        Whether the command takes ``--units`` (the hint says how to use it).
    defer : bool
        Do not print the warnings (the caller prints them with its result, so
        that a failure later is one line, see :func:`print_warnings`).

    Raises
    ------
    observer.cli.UserError
        For the first finding of severity ``"error"``.
    """
    from observer.cli import UserError

    warnings: list[str] = []
    for f in findings:
        text = (f"{path}: " if path else "") + f.text + units_hint(f.suggest, units_option)
        if f.severity == "error":
            raise UserError(text)
        warnings.append(text)
    if not defer:
        print_warnings(command, warnings)
    return warnings


def print_warnings(command: str, warnings: Iterable[str]) -> None:
    """Each warning as one line on stderr: ``dcobserver CMD: warning: ...``."""
    for text in warnings:
        print(f"dcobserver {command}: warning: {text}", file=sys.stderr, flush=True)


def finite_json(value: Any) -> Any:
    """``value`` ready for strict JSON: NaN and infinities become null (JSON has neither)."""
    from observer.service.mcaplog import json_safe

    return json_safe(value)


def table(rows: Sequence[Sequence[str]], align: str) -> list[str]:
    """Columns padded to their widest cell; ``align`` has one ``<`` or ``>`` per column."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(align))]
    out = []
    for r in rows:
        cells = [f"{c:{a}{w}}" for c, a, w in zip(r, align, widths, strict=True)]
        out.append("  ".join(cells).rstrip())
    return out
