"""ADC counts and their scale: the ``"adc"`` metadata convention.

A recording whose samples were measured by an ADC may say so in its metadata::

    "adc": {"va": {"lsb": 0.1, "offset": 0.0, "bits": 12}, "ia": {...}, ...}

meaning that every value of that channel is ``offset + lsb * count`` computed
in float64 for an integer ``count`` (``bits`` the converter's resolution, 0 if
not known). Files then store the integer counts and the scale instead of
float64 values: about a quarter of the bytes, and exact, because the count of
a value is recovered exactly and checked (:meth:`AdcScale.counts_of`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from observer.recording.base import CHANNELS, FloatArray, IntArray, Recording

ADC_KEY: Final = "adc"
"""Metadata key of the per-channel scales."""

_COUNT_LIMIT: Final = 2**31  # counts are stored as 32-bit signed integers


class AdcScale(NamedTuple):
    """How one channel's counts become SI values: ``offset + lsb * count``.

    Attributes
    ----------
    lsb : float
        SI units per count (> 0, finite).
    offset : float
        SI value of count 0.
    bits : int
        Resolution of the converter (0: not known); informative only.
    """

    lsb: float
    offset: float = 0.0
    bits: int = 0

    def values(self, counts: npt.ArrayLike) -> FloatArray:
        """SI values of integer ``counts`` (float64, the one formula every reader uses)."""
        return self.offset + self.lsb * np.asarray(counts, dtype=np.float64)

    def counts_of(self, values: npt.ArrayLike) -> IntArray | None:
        """The integer counts whose :meth:`values` are exactly ``values``, or None.

        None when any value is not exactly ``offset + lsb * count`` for an
        integer count within 32 bits (a value computed another way, a NaN): the
        caller then stores the values themselves, so nothing is ever rounded.
        """
        array = np.asarray(values, dtype=np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            counts = np.rint((array - self.offset) / self.lsb)
        if not np.isfinite(counts).all() or (np.abs(counts) >= _COUNT_LIMIT).any():
            return None
        integer = counts.astype(np.int64)
        if not np.array_equal(self.values(integer), array):
            return None
        return integer

    def as_metadata(self) -> dict[str, Any]:
        """The ``{"lsb", "offset", "bits"}`` object of the convention."""
        return {"lsb": self.lsb, "offset": self.offset, "bits": self.bits}


def scale_problem(lsb: object, offset: object, bits: object) -> str | None:
    """What is wrong with a scale's three numbers, or None."""
    if isinstance(lsb, bool) or not isinstance(lsb, int | float) or not math.isfinite(lsb):
        return f"lsb must be a finite number, got {lsb!r}"
    if not lsb > 0:
        return f"lsb must be > 0, got {lsb!r}"
    if isinstance(offset, bool) or not isinstance(offset, int | float):
        return f"offset must be a number, got {offset!r}"
    if not math.isfinite(offset):
        return f"offset must be finite, got {offset!r}"
    if isinstance(bits, bool) or not isinstance(bits, int) or not 0 <= bits <= 32:
        return f"bits must be an integer from 0 to 32, got {bits!r}"
    return None


def adc_scales(metadata: Mapping[str, Any]) -> dict[str, AdcScale]:
    """The scales a recording's metadata declares (empty if it has no ``"adc"``).

    Raises
    ------
    ValueError
        Naming the channel and field of a malformed entry.
    """
    table = metadata.get(ADC_KEY)
    if table is None:
        return {}
    if not isinstance(table, Mapping):
        raise ValueError(f"metadata {ADC_KEY!r} must be an object of channel -> scale")
    scales = {}
    for channel, entry in table.items():
        if channel not in CHANNELS:
            raise ValueError(f"metadata {ADC_KEY!r}: unknown channel {channel!r}")
        if not isinstance(entry, Mapping) or "lsb" not in entry:
            raise ValueError(f"metadata {ADC_KEY!r}.{channel}: needs an object with 'lsb'")
        lsb, offset, bits = entry["lsb"], entry.get("offset", 0.0), entry.get("bits", 0)
        problem = scale_problem(lsb, offset, bits)
        if problem:
            raise ValueError(f"metadata {ADC_KEY!r}.{channel}: {problem}")
        scales[channel] = AdcScale(float(lsb), float(offset), int(bits))
    return scales


def quantise(rec: Recording, full_scale: Mapping[str, float], *, bits: int = 12) -> Recording:
    """``rec`` as a bipolar ``bits``-bit ADC would have measured it, with ``"adc"`` metadata.

    Channel ``c`` spans ``[-full_scale[c], full_scale[c])`` in ``2**bits``
    counts; values beyond it saturate, as an ADC's do. Channels not in
    ``full_scale`` are kept as they are.

    Parameters
    ----------
    rec : Recording
    full_scale : Mapping[str, float]
        Channel -> full-scale magnitude in SI units (> 0).
    bits : int
        Resolution, 2 to 31.

    Returns
    -------
    Recording
        Same times; quantised channels exactly ``AdcScale.values(counts)``;
        metadata of ``rec`` plus ``"adc"``.
    """
    if not 2 <= bits <= 31:
        raise ValueError(f"bits must be from 2 to 31, got {bits}")
    signals = dict(rec.signals)
    table = dict(adc_scales(rec.metadata))
    half = 2 ** (bits - 1)
    for channel, magnitude in full_scale.items():
        if channel not in signals:
            raise ValueError(f"channel {channel!r} is not in the recording")
        if not (math.isfinite(magnitude) and magnitude > 0):
            raise ValueError(f"full scale of {channel!r} must be > 0, got {magnitude!r}")
        scale = AdcScale(lsb=magnitude / half, offset=0.0, bits=bits)
        counts = np.clip(np.rint(signals[channel] / scale.lsb), -half, half - 1)
        signals[channel] = scale.values(counts)
        table[channel] = scale
    metadata = {
        **rec.metadata,
        ADC_KEY: {c: s.as_metadata() for c, s in sorted(table.items(), key=_channel_order)},
    }
    return Recording(t=rec.t, signals=signals, metadata=metadata)


def _channel_order(item: tuple[str, AdcScale]) -> int:
    return CHANNELS.index(item[0])
