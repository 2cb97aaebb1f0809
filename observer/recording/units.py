"""Reading a recording whose columns are not in SI units: ``--units t=ms,ia=mA,omega=rpm``.

Recordings are SI (:data:`~observer.recording.base.UNITS`); a file from another
tool may hold milliseconds, milliamperes or rpm. :func:`parse_units` reads a
specification like ``"t=ms,ia=mA,omega=rpm"`` and :func:`to_si` converts a
recording with it. A leading ``-`` on a unit also inverts the sign
(``ia=-A``: a current sensor mounted the other way round).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Final

import numpy as np

from observer.recording.base import CHANNELS, Recording

#: Unit -> factor to SI, for each kind of column.
_TIME_UNITS: Final = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "min": 60.0}
_VOLTAGE_UNITS: Final = {"V": 1.0, "mV": 1e-3, "kV": 1e3}
_CURRENT_UNITS: Final = {"A": 1.0, "mA": 1e-3, "kA": 1e3}
_SPEED_UNITS: Final = {
    "rad/s": 1.0,
    "rpm": 2 * math.pi / 60,
    "Hz": 2 * math.pi,
    "rev/s": 2 * math.pi,
    "deg/s": math.pi / 180,
}
COLUMN_UNITS: Final[dict[str, dict[str, float]]] = {
    "t": _TIME_UNITS,
    "va": _VOLTAGE_UNITS,
    "vf": _VOLTAGE_UNITS,
    "ia": _CURRENT_UNITS,
    "if": _CURRENT_UNITS,
    "omega": _SPEED_UNITS,
}
"""Column -> the units it may be given in, each with its factor to SI."""


def parse_units(spec: str) -> dict[str, float]:
    """Read ``"t=ms,ia=mA,omega=rpm"`` into factors to SI per column.

    Parameters
    ----------
    spec : str
        Comma-separated ``COLUMN=UNIT``; ``-UNIT`` also inverts the sign.

    Returns
    -------
    dict
        Column -> factor (``{"t": 0.001, "ia": 0.001, "omega": 0.1047...}``).

    Raises
    ------
    ValueError
        A one-line message naming the bad item and what is allowed.
    """
    factors: dict[str, float] = {}
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        column, sep, unit = (part.strip() for part in item.partition("="))
        if not sep or not unit:
            raise ValueError(f"{item!r}: expected COLUMN=UNIT, e.g. t=ms or omega=rpm")
        if column not in COLUMN_UNITS:
            raise ValueError(
                f"{item!r}: unknown column {column!r}; columns: t, {', '.join(CHANNELS)}"
            )
        if column in factors:
            raise ValueError(f"{item!r}: column {column!r} given twice")
        sign = 1.0
        if unit.startswith("-"):
            if column == "t":
                raise ValueError(f"{item!r}: time cannot be inverted")
            sign, unit = -1.0, unit[1:]
        allowed = COLUMN_UNITS[column]
        unit = "us" if unit == "\u00b5s" else unit
        if unit not in allowed:
            raise ValueError(f"{item!r}: unit {unit!r} of {column}; allowed: {', '.join(allowed)}")
        factors[column] = sign * allowed[unit]
    if not factors:
        raise ValueError("no COLUMN=UNIT given, e.g. t=ms,ia=mA")
    return factors


def to_si(rec: Recording, factors: Mapping[str, float]) -> Recording:
    """The recording with each column multiplied by its factor (from :func:`parse_units`).

    The conversion is noted in the metadata under ``"units_converted"``.

    Raises
    ------
    observer.recording.RecordingError
        If a converted column is missing from the recording, or the converted
        time base is invalid.
    """
    from observer.recording.base import RecordingError

    for column in factors:
        if not rec.has(column):
            raise RecordingError(
                f"--units names {column!r}, which the recording does not have "
                f"(it has t, {', '.join(rec.channels)})",
                column=column,
            )
    signals = {c: np.asarray(rec.signals[c]) * factors.get(c, 1.0) for c in rec.channels}
    metadata = dict(rec.metadata)
    metadata["units_converted"] = {c: f for c, f in factors.items()}
    return Recording(t=rec.t * factors.get("t", 1.0), signals=signals, metadata=metadata)
