"""The measurement chain of a simulated drive: what happens to a signal between the motor and a
recorded number, one description per channel.

Per channel, in signal order (equations in ``docs/drive_chain.md``)::

    sensor        x_s = (1 + gain_error) * x + offset
    analog filter y = H(s) x_s        (none, Butterworth, Bessel or RC cascade, order 1..4)
    sampling      y(kT + delay)       or, averaging, (1/T) * integral of y over the period
                                      ending at kT + delay
    noise         + N(0, sigma^2)     white, at the ADC input
    ADC           offset_adc + lsb * clip(round((v - offset_adc) / lsb), -2^(b-1), 2^(b-1) - 1)
                  lsb = 2 * full_scale / 2^bits (bipolar range +-full_scale)

Filters and sampling run inside the drive kernel (:mod:`observer.simulation.converter_kernels`),
on the motor's waveforms integrated far finer than the sample rate; gain, offset, noise and
quantisation are applied to the sampled values here (:meth:`ResolvedChannel.measure`).

A :class:`ChannelChain` is what the user describes (a filter cutoff may be a fraction of the
sample rate, a full scale or a noise level may be left to the drive's sizing); a
:class:`ResolvedChannel` is the same channel with every number fixed for one sample rate and one
converter, which is what the recording's metadata reports. Bad values raise :class:`ValueError`
with a one-line message naming the key, e.g. ``chain.ia.cutoff_hz``.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from observer.recording import AdcScale

#: Channel order of every array in this package (the recording's channel names).
CHANNELS: tuple[str, ...] = ("va", "ia", "vf", "if", "omega")

#: Analog anti-aliasing filter families.
FILTER_KINDS: tuple[str, ...] = ("none", "butter", "bessel", "rc")

MAX_FILTER_ORDER = 4
MAX_ADC_BITS = 24

# Bessel (maximally flat delay) sections normalised to -3 dB at 1 rad/s: (w0, Q) per section,
# Q = 0 marks a first-order section (the poles of scipy.signal.bessel(N, 1, norm="mag")).
_BESSEL: dict[int, tuple[tuple[float, float], ...]] = {
    1: ((1.0, 0.0),),
    2: ((1.2720196495140679, 0.5773502691896257),),
    3: ((1.3226757999104441, 0.0), (1.4476171331469865, 0.6910466258250713)),
    4: ((1.4301715599939884, 0.5219345816689802), (1.6033575162169704, 0.8055382818416656)),
}


@dataclass(frozen=True)
class ChannelChain:
    """One channel's front end as described by the user; ``None`` fields are filled in later.

    Attributes
    ----------
    filter : str
        Anti-aliasing filter family: ``none``, ``butter`` (Butterworth), ``bessel`` or ``rc``
        (a cascade of equal first-order RC stages).
    order : int
        Filter order, 1..4 (0 with ``none``).
    cutoff_hz : float or None
        The filter's -3 dB frequency (Hz), for every family.
    cutoff_per_fs : float or None
        The -3 dB frequency as a fraction of the sample rate (0.25 = fs/4); exactly one of
        ``cutoff_hz`` and ``cutoff_per_fs`` is set when there is a filter.
    delay_s : float
        Sampling instant after the nominal one (s): a multiplexed ADC converts the channels one
        after another. ``0 <= delay_s < 1/fs``.
    gain_error : float
        Relative sensor gain error (0.01 = reads 1 % high).
    offset : float
        Sensor offset in the channel's SI unit (V, A or rad/s).
    bits : int or None
        ADC resolution; ``None``: not quantised.
    full_scale : float or None
        The ADC's bipolar range +-full_scale (SI unit); ``None``: from the converter's sizing.
    noise : float or None
        White noise at the ADC input, as a fraction of the channel's rated value (0.002 =
        0.2 %); ``None``: the recording's noise level.
    averaging : bool
        An integrating measurement: the sample is the mean of the filtered signal over the
        sample period that ends at the sampling instant (as a V/f or integrating converter
        delivers it).
    """

    filter: str = "none"
    order: int = 0
    cutoff_hz: float | None = None
    cutoff_per_fs: float | None = None
    delay_s: float = 0.0
    gain_error: float = 0.0
    offset: float = 0.0
    bits: int | None = None
    full_scale: float | None = None
    noise: float | None = None
    averaging: bool = False

    def check(self, key: str = "chain") -> None:
        """Raise :class:`ValueError` naming ``key.field`` if a value is impossible by itself."""
        if self.filter not in FILTER_KINDS:
            raise ValueError(
                f"{key}.filter: unknown filter {self.filter!r} (expected {', '.join(FILTER_KINDS)})"
            )
        if self.filter == "none":
            if self.order != 0:
                raise ValueError(f"{key}.order: a channel without filter has order 0")
        else:
            if isinstance(self.order, bool) or not isinstance(self.order, int):
                raise ValueError(f"{key}.order: must be an integer, got {self.order!r}")
            if not 1 <= self.order <= MAX_FILTER_ORDER:
                raise ValueError(
                    f"{key}.order: filter order must be 1..{MAX_FILTER_ORDER}, got {self.order}"
                )
            if (self.cutoff_hz is None) == (self.cutoff_per_fs is None):
                raise ValueError(
                    f"{key}.cutoff_hz: a {self.filter} filter needs one cutoff "
                    "(in Hz, or as a fraction of the sample rate)"
                )
            for name in ("cutoff_hz", "cutoff_per_fs"):
                value = getattr(self, name)
                if value is not None and not (math.isfinite(value) and value > 0):
                    raise ValueError(f"{key}.{name}: must be > 0, got {value!r}")
        _finite(self.delay_s, f"{key}.delay_s")
        if self.delay_s < 0:
            raise ValueError(f"{key}.delay_s: must be >= 0, got {self.delay_s!r}")
        _finite(self.gain_error, f"{key}.gain_error")
        if self.gain_error <= -1:
            raise ValueError(f"{key}.gain_error: must be > -1, got {self.gain_error!r}")
        _finite(self.offset, f"{key}.offset")
        if self.bits is not None:
            if isinstance(self.bits, bool) or not isinstance(self.bits, int):
                raise ValueError(f"{key}.bits: must be an integer, got {self.bits!r}")
            if not 1 <= self.bits <= MAX_ADC_BITS:
                raise ValueError(
                    f"{key}.bits: ADC resolution must be 1..{MAX_ADC_BITS} bits, got {self.bits}"
                )
        if self.full_scale is not None and not (
            math.isfinite(self.full_scale) and self.full_scale > 0
        ):
            raise ValueError(f"{key}.full_scale: must be > 0, got {self.full_scale!r}")
        if self.noise is not None and not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"{key}.noise: must be >= 0, got {self.noise!r}")
        if not isinstance(self.averaging, bool):
            raise ValueError(f"{key}.averaging: must be true or false, got {self.averaging!r}")

    def check_rate(self, sample_rate_hz: float, key: str = "chain") -> None:
        """Raise :class:`ValueError` if the channel cannot work at ``sample_rate_hz``."""
        nyquist = sample_rate_hz / 2
        cutoff = self.cutoff_at(sample_rate_hz)
        if cutoff is not None and cutoff > nyquist:
            name = "cutoff_hz" if self.cutoff_hz is not None else "cutoff_per_fs"
            raise ValueError(
                f"{key}.{name}: cutoff {cutoff:g} Hz is above the Nyquist frequency "
                f"{nyquist:g} Hz of {sample_rate_hz:g} Hz sampling"
            )
        period = 1.0 / sample_rate_hz
        if self.delay_s >= period:
            raise ValueError(
                f"{key}.delay_s: {self.delay_s:g} s is not below one sample period "
                f"({period:g} s at {sample_rate_hz:g} Hz)"
            )

    def cutoff_at(self, sample_rate_hz: float) -> float | None:
        """The -3 dB frequency (Hz) at ``sample_rate_hz``; ``None`` without a filter."""
        if self.filter == "none":
            return None
        if self.cutoff_hz is not None:
            return float(self.cutoff_hz)
        assert self.cutoff_per_fs is not None
        return float(self.cutoff_per_fs * sample_rate_hz)

    def replace(self, **changes: Any) -> ChannelChain:
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class MeasurementChain:
    """The front ends of the five channels ``va, ia, vf, if, omega`` (:data:`CHANNELS`)."""

    channels: tuple[ChannelChain, ...] = (ChannelChain(),) * len(CHANNELS)

    def __post_init__(self) -> None:
        if len(self.channels) != len(CHANNELS):
            raise ValueError(f"chain: needs {len(CHANNELS)} channels, got {len(self.channels)}")
        for name, ch in zip(CHANNELS, self.channels, strict=True):
            if not isinstance(ch, ChannelChain):
                raise ValueError(f"chain.{name}: not a ChannelChain: {ch!r}")
            ch.check(f"chain.{name}")

    @classmethod
    def uniform(cls, channel: ChannelChain) -> MeasurementChain:
        """The same front end on every channel."""
        return cls((channel,) * len(CHANNELS))

    def __getitem__(self, name: str) -> ChannelChain:
        return self.channels[_index(name)]

    def items(self) -> Iterator[tuple[str, ChannelChain]]:
        return zip(CHANNELS, self.channels, strict=True)

    def with_channel(self, name: str, **changes: Any) -> MeasurementChain:
        """This chain with fields of channel ``name`` changed (validated)."""
        i = _index(name)
        channels = list(self.channels)
        channels[i] = dataclasses.replace(channels[i], **changes)
        return MeasurementChain(tuple(channels))

    def check_rate(self, sample_rate_hz: float) -> None:
        """Raise :class:`ValueError` naming the channel and key that ``sample_rate_hz`` breaks."""
        for name, ch in self.items():
            ch.check_rate(sample_rate_hz, f"chain.{name}")


@dataclass(frozen=True)
class ResolvedChannel:
    """One channel with every number fixed: what the recording's metadata says.

    Attributes are those of :class:`ChannelChain` with ``cutoff_hz`` in Hz (``None`` without a
    filter), ``full_scale`` in SI units, ``noise_std`` the noise's standard deviation in SI units
    and ``noise`` the same as a fraction of ``rated``, the channel's rated value.
    """

    filter: str
    order: int
    cutoff_hz: float | None
    delay_s: float
    gain_error: float
    offset: float
    bits: int | None
    full_scale: float
    noise: float
    noise_std: float
    averaging: bool
    rated: float

    @property
    def lsb(self) -> float | None:
        """Value of one ADC count (SI units); ``None`` if not quantised."""
        if self.bits is None:
            return None
        return 2.0 * self.full_scale / 2.0**self.bits

    def sections(self) -> np.ndarray:
        """The filter as the kernel takes it: ``(2, 3)`` rows of ``(kind, w0 rad/s, Q)``.

        ``kind`` 0 is an unused section, 1 a first-order lag ``w0/(s + w0)``, 2 a second-order
        low pass ``w0^2/(s^2 + (w0/Q) s + w0^2)``.
        """
        return filter_sections(self.filter, self.order, self.cutoff_hz)

    def measure(self, analog: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Sampled (filtered) values -> recorded values: gain, offset, noise, ADC."""
        x = analog * (1.0 + self.gain_error) + self.offset
        if self.noise_std > 0:
            x = x + rng.standard_normal(x.shape) * self.noise_std
        lsb = self.lsb
        if lsb is None or self.bits is None:
            return np.asarray(x, dtype=float)
        return quantise(x, lsb, self.bits)

    def adc_metadata(self) -> dict[str, Any] | None:
        """``{"lsb", "offset", "bits"}``: value = offset + lsb * count exactly (the convention
        of :mod:`observer.recording.adc`); ``None`` if the channel is not quantised."""
        if self.bits is None or self.lsb is None:
            return None
        return AdcScale(self.lsb, ADC_OFFSET, self.bits).as_metadata()

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: The ADC's zero: counts are signed (two's complement), so value = 0.0 + lsb * count.
ADC_OFFSET = 0.0


def quantise(x: np.ndarray, lsb: float, bits: int, offset: float = ADC_OFFSET) -> np.ndarray:
    """``offset + lsb * count`` with ``count = round((x - offset) / lsb)`` clipped to the
    signed range of a ``bits``-bit ADC (it saturates at full scale)."""
    lo = -(2.0 ** (bits - 1))
    hi = 2.0 ** (bits - 1) - 1
    counts = np.clip(np.rint((np.asarray(x, dtype=float) - offset) / lsb), lo, hi)
    result: np.ndarray = AdcScale(lsb, offset, bits).values(counts)
    return result


def filter_sections(kind: str, order: int, cutoff_hz: float | None) -> np.ndarray:
    """Sections ``(kind, w0, Q)`` (see :meth:`ResolvedChannel.sections`) of a low pass with its
    -3 dB point at ``cutoff_hz``; at most two sections (order <= 4)."""
    out = np.zeros((2, 3))
    if kind == "none" or order == 0:
        return out
    if cutoff_hz is None:
        raise ValueError(f"a {kind} filter needs a cutoff")
    wc = 2.0 * math.pi * cutoff_hz
    secs: list[tuple[float, float]]
    if kind == "butter":
        secs = [(1.0, 1.0 / (2.0 * math.sin(math.pi * (2 * k + 1) / (2 * order))))
                for k in range(order // 2)]  # fmt: skip
        if order % 2:
            secs.append((1.0, 0.0))
    elif kind == "bessel":
        secs = list(_BESSEL[order])
    elif kind == "rc":
        # n equal stages, -3 dB of the cascade at wc: each stage's corner is wc/sqrt(2^(1/n)-1);
        # two equal first-order stages make one second-order section with Q = 1/2.
        stage = 1.0 / math.sqrt(2.0 ** (1.0 / order) - 1.0)
        secs = [(stage, 0.5)] * (order // 2)
        if order % 2:
            secs.append((stage, 0.0))
    else:
        raise ValueError(f"unknown filter {kind!r}")
    for i, (w0, q) in enumerate(secs):
        out[i] = (1.0 if q == 0.0 else 2.0, w0 * wc, q)
    return out


def frequency_response(sections: np.ndarray, f_hz: np.ndarray | float) -> np.ndarray:
    """Complex response of :func:`filter_sections` at ``f_hz`` (for checks and the docs)."""
    s = 2j * math.pi * np.asarray(f_hz, dtype=float)
    h = np.ones_like(s)
    for kind, w0, q in sections:
        if kind == 1:
            h = h * w0 / (s + w0)
        elif kind == 2:
            h = h * w0 * w0 / (s * s + (w0 / q) * s + w0 * w0)
    return h


def resolve_chain(
    chain: MeasurementChain,
    sample_rate_hz: float,
    *,
    full_scale: Mapping[str, float],
    rated: Mapping[str, float],
    noise: Mapping[str, float],
) -> tuple[ResolvedChannel, ...]:
    """Fix every number of ``chain`` for one sample rate and one drive.

    Parameters
    ----------
    full_scale, rated : mapping of channel name to float
        Default ADC full scale and the rated value (SI) of each channel.
    noise : mapping of channel name to float
        Noise fraction of channels whose chain leaves it unset.
    """
    chain.check_rate(sample_rate_hz)
    out = []
    for name, ch in chain.items():
        fraction = ch.noise if ch.noise is not None else noise[name]
        out.append(
            ResolvedChannel(
                filter=ch.filter, order=ch.order, cutoff_hz=ch.cutoff_at(sample_rate_hz),
                delay_s=float(ch.delay_s), gain_error=float(ch.gain_error),
                offset=float(ch.offset), bits=ch.bits,
                full_scale=float(ch.full_scale if ch.full_scale is not None
                                 else full_scale[name]),
                noise=float(fraction), noise_std=float(fraction * rated[name]),
                averaging=bool(ch.averaging), rated=float(rated[name]),
            )
        )  # fmt: skip
    return tuple(out)


# ------------------------------------------------------------------ the option mini-language

_FILTER_RE = re.compile(
    r"^\s*(?P<kind>[a-z]+?)(?P<order>\d+)?\s*(@\s*(?P<cutoff>[^@]+?))?\s*$", re.IGNORECASE
)
_FS_RE = re.compile(r"^fs\s*/\s*(?P<div>[0-9.eE+-]+)$", re.IGNORECASE)

T = TypeVar("T")


def parse_filter(text: str) -> dict[str, Any]:
    """``none`` or ``KIND ORDER @ CUTOFF`` -> fields of :class:`ChannelChain`.

    ``KIND`` is ``butter``, ``bessel`` or ``rc``, ``ORDER`` 1..4, ``CUTOFF`` the -3 dB
    frequency in Hz (``500``, ``500hz``) or a fraction of the sample rate (``fs/4``), e.g.
    ``butter2@fs/4``, ``rc1@500``.
    """
    raw = text.strip().lower()
    if raw in ("none", "0", "off"):
        return {"filter": "none", "order": 0, "cutoff_hz": None, "cutoff_per_fs": None}
    m = _FILTER_RE.match(raw)
    if not m:
        raise ValueError(f"filter {text!r} is not KIND ORDER@CUTOFF, e.g. butter2@fs/4 or rc1@500")
    kind = m["kind"]
    if kind not in FILTER_KINDS or kind == "none":
        raise ValueError(
            f"unknown filter {kind!r} in {text!r} (expected none, butter, bessel or rc)"
        )
    if m["order"] is None:
        raise ValueError(f"filter {text!r} has no order (e.g. {kind}2@fs/4)")
    order = int(m["order"])
    if not 1 <= order <= MAX_FILTER_ORDER:
        raise ValueError(f"filter order must be 1..{MAX_FILTER_ORDER}, got {order} in {text!r}")
    if m["cutoff"] is None:
        raise ValueError(f"filter {text!r} has no cutoff (e.g. {kind}{order}@500 or @fs/4)")
    cutoff = m["cutoff"].strip()
    fs = _FS_RE.match(cutoff)
    if fs:
        div = _number(fs["div"], f"cutoff {cutoff!r}")
        if not div > 0:
            raise ValueError(f"cutoff {cutoff!r}: the divisor must be > 0")
        return {"filter": kind, "order": order, "cutoff_hz": None, "cutoff_per_fs": 1.0 / div}
    if cutoff.endswith("hz"):
        cutoff = cutoff[:-2].strip()
    hz = _number(cutoff, f"cutoff {m['cutoff'].strip()!r}")
    if not hz > 0:
        raise ValueError(f"cutoff must be > 0 Hz, got {hz:g}")
    return {"filter": kind, "order": order, "cutoff_hz": hz, "cutoff_per_fs": None}


def parse_per_channel(text: str, convert: Callable[[str], T]) -> dict[str, T]:
    """``VALUE`` for every channel, ``CH=VALUE,...`` for some, or both (``VALUE,CH=VALUE``:
    the bare value for all channels, then the named ones).

    Returns ``{channel: value}`` with ``"*"`` for the bare value. ``convert`` turns one value's
    text into a value and raises :class:`ValueError` on bad text.
    """
    out: dict[str, T] = {}
    for item in _split_items(text):
        name, sep, value = item.partition("=")
        if not sep:
            if "*" in out:
                raise ValueError(f"two values for every channel in {text!r}")
            out["*"] = convert(item)
            continue
        name = name.strip()
        if name not in CHANNELS:
            raise ValueError(f"unknown channel {name!r} (expected {', '.join(CHANNELS)})")
        if name in out:
            raise ValueError(f"channel {name} given twice in {text!r}")
        try:
            out[name] = convert(value.strip())
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None
    if not out:
        raise ValueError("no value given")
    return out


def apply_per_channel(
    chain: MeasurementChain, values: Mapping[str, Mapping[str, Any]]
) -> MeasurementChain:
    """``chain`` with field changes per channel (``"*"``: every channel, applied first)."""
    result = chain
    if "*" in values:
        try:
            for name in CHANNELS:
                result = result.with_channel(name, **values["*"])
        except ValueError as exc:
            # a value for every channel fails on the first one: name the key, not the channel
            raise ValueError(re.sub(r"^chain\.[a-z]+\.", "chain.", str(exc))) from None
    for name, changes in values.items():
        if name != "*":
            result = result.with_channel(name, **changes)
    return result


def _split_items(text: str) -> list[str]:
    # A filter's "fs/4" has no comma, so items split on commas alone.
    return [item.strip() for item in text.split(",") if item.strip()]


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ValueError(f"{what} is not a number") from None
    if not math.isfinite(value):
        raise ValueError(f"{what} is not finite")
    return value


def _finite(value: Any, key: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{key}: must be a finite number, got {value!r}")


def _index(name: str) -> int:
    try:
        return CHANNELS.index(name)
    except ValueError:
        raise ValueError(f"unknown channel {name!r} (expected {', '.join(CHANNELS)})") from None
