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

One description for the simulator and the estimator: a :class:`ChannelChain` *is* the
estimator's :class:`~observer.estimation.frontend.FrontEnd` (filter, delay, averaging: the
``[chain]`` grammar of :mod:`observer.config`, filters in :func:`observer.config.parse_filter`,
sections in :func:`observer.estimation.frontend.filter_sections`) plus what only a simulation
knows: sensor gain error and offset, ADC bits and range, noise (the ``[sensors]`` table of a
drive file, :mod:`observer.simulation.converter`). :meth:`MeasurementChain.to_config` is the
``[chain]`` the estimator is given for such a recording, :meth:`MeasurementChain.with_config`
reads one.

A :class:`ChannelChain` is what the user describes (a filter cutoff may be a fraction of the
sample rate, a full scale or a noise level may be left to the drive's sizing); a
:class:`ResolvedChannel` is the same channel with every number fixed for one sample rate and one
converter, which is what the recording's metadata reports. Bad values raise :class:`ValueError`
with a one-line message naming the key, e.g. ``chain.ia.filter`` or ``sensors.ia.bits``.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from observer.config import (
    FILTER_KINDS,
    MAX_FILTER_ORDER,
    ChainConfig,
    ChannelFrontEnd,
    parse_filter,
)
from observer.estimation.frontend import FrontEnd, filter_sections
from observer.recording import AdcScale

#: Channel order of every array in this package (the recording's channel names).
CHANNELS: tuple[str, ...] = ("va", "ia", "vf", "if", "omega")

MAX_ADC_BITS = 24

#: Where each key of a channel lives in a drive file: the ``[chain]`` grammar the estimator
#: shares, or the simulator's own ``[sensors]`` table.
FRONT_END_KEYS: tuple[str, ...] = ("filter", "delay_us", "averaging")
SENSOR_KEYS: tuple[str, ...] = ("bits", "full_scale", "noise", "gain_error", "offset")


def _table(field: str) -> str:
    """The drive-file table of a :class:`ChannelChain` field (for error messages)."""
    return "sensors" if field in SENSOR_KEYS else "chain"


@dataclass(frozen=True)
class ChannelChain(FrontEnd):
    """One channel's front end as described by the user; ``None`` fields are filled in later.

    The fields of :class:`~observer.estimation.frontend.FrontEnd` (``filter``, ``order``,
    ``cutoff_hz``, ``cutoff_per_fs``, ``delay_s``, ``averaging``: the ``[chain]`` grammar),
    and:

    Attributes
    ----------
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

    ``delay_s`` is the sampling instant after the nominal one (s; ``delay_us`` in files and
    options, ``0 <= delay < 1/fs``); ``averaging`` an integrating measurement, the mean of the
    filtered signal over the period that ends at the sampling instant (a V/f or integrating
    converter).
    """

    gain_error: float = 0.0
    offset: float = 0.0
    bits: int | None = None
    full_scale: float | None = None
    noise: float | None = None

    def check(self, key: str = "chain") -> None:
        """Raise :class:`ValueError` if a value is impossible by itself.

        The message names ``KEY.field`` with ``key`` the channel's ``chain.CH`` (its
        ``[sensors]`` fields are named ``sensors.CH.field``).
        """

        def where(field: str) -> str:
            return re.sub(r"^chain\b", _table(field), key) + "." + field

        if self.filter not in FILTER_KINDS:
            raise ValueError(
                f"{where('filter')}: unknown filter {self.filter!r} "
                f"(expected {', '.join(FILTER_KINDS)})"
            )
        if self.filter == "none":
            if self.order != 0:
                raise ValueError(f"{where('order')}: a channel without filter has order 0")
        else:
            if isinstance(self.order, bool) or not isinstance(self.order, int):
                raise ValueError(f"{where('order')}: must be an integer, got {self.order!r}")
            if not 1 <= self.order <= MAX_FILTER_ORDER:
                raise ValueError(
                    f"{where('order')}: filter order must be 1..{MAX_FILTER_ORDER}, "
                    f"got {self.order}"
                )
            if (self.cutoff_hz is None) == (self.cutoff_per_fs is None):
                raise ValueError(
                    f"{where('cutoff_hz')}: a {self.filter} filter needs one cutoff "
                    "(in Hz, or as a fraction of the sample rate)"
                )
            for name in ("cutoff_hz", "cutoff_per_fs"):
                value = getattr(self, name)
                if value is not None and not (math.isfinite(value) and value > 0):
                    raise ValueError(f"{where(name)}: must be > 0, got {value!r}")
        _finite(self.delay_s, where("delay_us"))
        if self.delay_s < 0:
            raise ValueError(f"{where('delay_us')}: must be >= 0, got {self.delay_s * 1e6:g}")
        _finite(self.gain_error, where("gain_error"))
        if self.gain_error <= -1:
            raise ValueError(f"{where('gain_error')}: must be > -1, got {self.gain_error!r}")
        _finite(self.offset, where("offset"))
        if self.bits is not None:
            if isinstance(self.bits, bool) or not isinstance(self.bits, int):
                raise ValueError(f"{where('bits')}: must be an integer, got {self.bits!r}")
            if not 1 <= self.bits <= MAX_ADC_BITS:
                raise ValueError(
                    f"{where('bits')}: ADC resolution must be 1..{MAX_ADC_BITS} bits, "
                    f"got {self.bits}"
                )
        if self.full_scale is not None and not (
            math.isfinite(self.full_scale) and self.full_scale > 0
        ):
            raise ValueError(f"{where('full_scale')}: must be > 0, got {self.full_scale!r}")
        if self.noise is not None and not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"{where('noise')}: must be >= 0, got {self.noise!r}")
        if not isinstance(self.averaging, bool):
            raise ValueError(f"{where('averaging')}: must be true or false, got {self.averaging!r}")

    def check_rate(self, sample_rate_hz: float, key: str = "chain") -> None:
        """Raise :class:`ValueError` naming ``key.filter`` or ``key.delay_us`` if the channel
        cannot work at ``sample_rate_hz`` (the limits of
        :func:`observer.estimation.frontend.check_against_rate`)."""
        nyquist = sample_rate_hz / 2
        cutoff = self.cutoff_at(sample_rate_hz)
        if cutoff is not None and cutoff >= nyquist:
            raise ValueError(
                f"{key}.filter: cutoff {cutoff:g} Hz is at or above the Nyquist frequency "
                f"{nyquist:g} Hz of {sample_rate_hz:g} Hz sampling"
            )
        period = 1.0 / sample_rate_hz
        if self.delay_s >= period:
            raise ValueError(
                f"{key}.delay_us: {self.delay_s * 1e6:g} us is not below one sample period "
                f"({period * 1e6:g} us at {sample_rate_hz:g} Hz)"
            )

    def cutoff_at(self, sample_rate_hz: float) -> float | None:
        """The -3 dB frequency (Hz) at ``sample_rate_hz``; ``None`` without a filter."""
        if self.filter == "none":
            return None
        return super().cutoff_at(sample_rate_hz)

    def filter_text(self) -> str:
        """The filter in the grammar of :func:`observer.config.parse_filter` (``butter2@fs/4``)."""
        if self.filter == "none":
            return "none"
        if self.cutoff_per_fs is not None:
            return f"{self.filter}{self.order}@fs/{1.0 / self.cutoff_per_fs:.12g}"
        return f"{self.filter}{self.order}@{self.cutoff_hz:.12g}"

    def front_end_config(self) -> ChannelFrontEnd:
        """This channel as the estimator's ``[chain.CH]`` table describes it."""
        return ChannelFrontEnd(
            filter=self.filter_text(),
            delay_us=round(self.delay_s * 1e6, 9),
            averaging=self.averaging,
        )

    def replace(self, **changes: Any) -> ChannelChain:
        return dataclasses.replace(self, **changes)


#: The field of :class:`observer.config.ChainConfig` per channel (``if`` is ``i_f`` there).
CONFIG_FIELDS: dict[str, str] = {
    f.metadata.get("key", f.name): f.name
    for f in dataclasses.fields(ChainConfig)
    if f.name != "intersample"
}


def front_end_changes(
    table: ChannelFrontEnd, given: Iterator[str] | Any = FRONT_END_KEYS
) -> dict[str, Any]:
    """:class:`ChannelChain` fields of a ``[chain.CH]`` table's keys ``given`` (default: all):
    the filter parsed by :func:`observer.config.parse_filter`, ``delay_us`` to seconds."""
    out: dict[str, Any] = {}
    for key in given:
        if key == "filter" and table.filter is not None:
            out |= parse_filter(table.filter)
        elif key == "delay_us":
            out["delay_s"] = table.delay_us / 1e6
        elif key == "averaging":
            out["averaging"] = table.averaging
    return out


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

    def to_config(self, intersample: str = "auto") -> ChainConfig:
        """The estimator's ``[chain]`` for a recording made through this chain.

        Filters, delays and averaging carry over exactly; what the estimator is not told
        (sensor errors, ADC, noise) stays out.
        """
        tables = {CONFIG_FIELDS[name]: ch.front_end_config() for name, ch in self.items()}
        return ChainConfig(intersample=intersample, **tables)

    def with_config(self, config: ChainConfig) -> MeasurementChain:
        """This chain with the front ends an estimator's ``[chain]`` knows (``filter`` set)."""
        result = self
        for name, field in CONFIG_FIELDS.items():
            table = getattr(config, field)
            if table.known:
                result = result.with_channel(name, **front_end_changes(table))
        return result


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

T = TypeVar("T")


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
            raise ValueError(re.sub(r"^(chain|sensors)\.[a-z]+\.", r"\1.", str(exc))) from None
    for name, changes in values.items():
        if name != "*":
            result = result.with_channel(name, **changes)
    return result


def _split_items(text: str) -> list[str]:
    # A filter's "fs/4" has no comma, so items split on commas alone.
    return [item.strip() for item in text.split(",") if item.strip()]


def _finite(value: Any, key: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{key}: must be a finite number, got {value!r}")


def _index(name: str) -> int:
    try:
        return CHANNELS.index(name)
    except ValueError:
        raise ValueError(f"unknown channel {name!r} (expected {', '.join(CHANNELS)})") from None
