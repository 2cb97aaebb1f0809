"""The sample-block message: how samples travel in MCAP files (and the daemon's log).

One JSON message on :data:`SAMPLES_TOPIC` per block of samples,
``{"t_ns": [...], "va": [...], ...}`` (see :data:`SAMPLE_BLOCK_SCHEMA`), and the
recording's metadata in a Metadata record named :data:`METADATA_NAME`. Times
are integer nanoseconds.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from observer.recording.base import CHANNELS, UNITS, FloatArray, IntArray

MEANINGS: Final[dict[str, str]] = {
    "t": "time",
    "va": "armature voltage",
    "ia": "armature current",
    "vf": "field voltage",
    "if": "field current",
    "omega": "shaft angular speed",
}
"""What the time column and each channel measure (units: :data:`UNITS`)."""

SAMPLES_TOPIC: Final = "/samples"
SAMPLES_SCHEMA_NAME: Final = "dcobserver.SampleBlock"
METADATA_NAME: Final = "dcobserver.recording"

SAMPLE_BLOCK_SCHEMA: Final[dict[str, Any]] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": SAMPLES_SCHEMA_NAME,
    "description": (
        "A block of uniformly sampled DC-motor winding signals. Every array has the "
        "length of t_ns; at least one signal is present."
    ),
    "type": "object",
    "properties": {
        "t_ns": {
            "description": "Sample times, integer nanoseconds.",
            "type": "array",
            "items": {"type": "integer"},
            "minItems": 1,
        },
        **{
            name: {
                "description": f"{MEANINGS[name].capitalize()} ({UNITS[name]}).",
                "type": "array",
                "items": {"type": "number"},
                "minItems": 1,
            }
            for name in CHANNELS
        },
    },
    "required": ["t_ns"],
    "minProperties": 2,
    "additionalProperties": False,
}
"""JSON schema (draft 2020-12) of one message on :data:`SAMPLES_TOPIC`."""

NS_PER_S: Final = 1e9
"""Nanoseconds per second: MCAP times are integer nanoseconds."""


class _SampleBlockError(ValueError):
    """A malformed sample block; ``column`` names the field concerned, if any."""

    def __init__(self, text: str, column: str | None = None) -> None:
        super().__init__(text)
        self.column = column


def _checked_block(t_ns: npt.ArrayLike, signals: Mapping[str, npt.ArrayLike]) -> npt.NDArray[Any]:
    """``t_ns`` as an array, after the checks every sample-block encoder makes."""
    times = np.asarray(t_ns)
    if times.ndim != 1 or times.size == 0:
        raise ValueError(f"t_ns must be a non-empty 1-D array, got shape {times.shape}")
    if times.dtype.kind not in "iu":
        raise ValueError(f"t_ns must hold integer nanoseconds, got dtype {times.dtype}")
    unknown = [name for name in signals if name not in CHANNELS]
    if unknown:
        raise ValueError(f"unknown channel {unknown[0]!r}; allowed: {', '.join(CHANNELS)}")
    if not signals:
        raise ValueError(f"a sample block needs at least one of {', '.join(CHANNELS)}")
    return times


def sample_block_message(t_ns: npt.ArrayLike, signals: Mapping[str, npt.ArrayLike]) -> bytes:
    """Encode one block of samples as the JSON message of :data:`SAMPLES_TOPIC`.

    Parameters
    ----------
    t_ns : array_like of int
        Sample times, integer nanoseconds; non-empty, 1-D.
    signals : Mapping[str, array_like]
        Channels (a non-empty subset of :data:`CHANNELS`) to arrays of the
        length of ``t_ns``; finite values only (JSON has no NaN).

    Returns
    -------
    bytes
        UTF-8 JSON ``{"t_ns": [...], "va": [...], ...}``, channels in
        :data:`CHANNELS` order, floats in shortest round-trip form.

    Raises
    ------
    ValueError
        If the inputs break any of the rules above.
    """
    times = _checked_block(t_ns, signals)
    block: dict[str, list[Any]] = {"t_ns": times.tolist()}
    for name in CHANNELS:
        if name not in signals:
            continue
        values = np.asarray(signals[name])
        if values.dtype.kind not in "iuf":
            raise ValueError(f"{name!r} must hold numbers, got dtype {values.dtype}")
        if values.shape != times.shape:
            raise ValueError(f"{name!r} has shape {values.shape} but t_ns has {times.shape}")
        bad = ~np.isfinite(values)
        if bad.any():
            index = int(np.argmax(bad))
            raise ValueError(f"{name!r}[{index}] is {values[index]}; JSON cannot carry it")
        block[name] = values.astype(np.float64).tolist()
    return json.dumps(block, separators=(",", ":"), allow_nan=False).encode("utf-8")


def _block_array(value: object, name: str, *, integer: bool) -> npt.NDArray[Any]:
    if not isinstance(value, list):
        raise _SampleBlockError(f"{name!r} must be a JSON array", name)
    if not value:
        raise _SampleBlockError(f"{name!r} is empty", name)
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        raise _SampleBlockError(f"{name!r} must be a flat array of numbers", name) from None
    if array.ndim != 1:
        raise _SampleBlockError(f"{name!r} must be a flat array of numbers", name)
    if integer:
        if array.dtype.kind not in "iu":
            raise _SampleBlockError(f"{name!r} must hold integer nanoseconds", name)
        if array.dtype.kind == "u" and int(array.max()) > np.iinfo(np.int64).max:
            raise _SampleBlockError(f"{name!r} holds a time beyond the int64 range", name)
        return array.astype(np.int64)
    if array.dtype.kind not in "iuf":
        raise _SampleBlockError(f"{name!r} must hold numbers", name)
    return array.astype(np.float64)


def parse_sample_block(data: bytes) -> tuple[IntArray, dict[str, FloatArray]]:
    """Decode one :data:`SAMPLES_TOPIC` message (inverse of :func:`sample_block_message`).

    Parameters
    ----------
    data : bytes
        The UTF-8 JSON message.

    Returns
    -------
    t_ns : numpy.ndarray of int64
        Sample times, integer nanoseconds.
    signals : dict[str, numpy.ndarray of float64]
        The channels present, in :data:`CHANNELS` order. Non-finite values
        written as the non-standard ``NaN``/``Infinity`` are passed through, for
        the caller's validation to report with their location.

    Raises
    ------
    ValueError
        If the message is not JSON, not an object, has unknown fields, lacks
        ``t_ns`` or every channel, or holds arrays of unequal length.
    """
    try:
        block = json.loads(data)
    except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError
        raise _SampleBlockError(f"not valid JSON: {exc}") from None
    if not isinstance(block, dict):
        raise _SampleBlockError(f"expected a JSON object, got {type(block).__name__}")
    for key in block:
        if key != "t_ns" and key not in CHANNELS:
            raise _SampleBlockError(
                f"unknown field {key!r}; allowed: t_ns, {', '.join(CHANNELS)}", key
            )
    if "t_ns" not in block:
        raise _SampleBlockError("missing field 't_ns'", "t_ns")
    t_ns = _block_array(block["t_ns"], "t_ns", integer=True)
    signals: dict[str, FloatArray] = {}
    for name in CHANNELS:
        if name in block:
            values = _block_array(block[name], name, integer=False)
            if values.size != t_ns.size:
                raise _SampleBlockError(
                    f"signals of unequal length: {name!r} has {values.size} samples "
                    f"but 't_ns' has {t_ns.size}",
                    name,
                )
            signals[name] = values
    if not signals:
        raise _SampleBlockError(f"no signal field; need at least one of {', '.join(CHANNELS)}")
    return t_ns, signals
