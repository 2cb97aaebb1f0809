"""The measurement front end of a channel, as the estimator models it.

Between the motor and a recorded number each channel passes an analog
anti-aliasing filter ``H(s)`` (none, Butterworth, Bessel or a cascade of RC
stages, order 1-4, a -3 dB cutoff), is sampled at the nominal instant plus a
delay (a multiplexed ADC converts the channels one after another), or is
averaged over the period ending there (an integrating converter). Voltage and
current channels often differ. Since the winding is linear, the measured
current is the winding's response to the voltage seen through the *relative*
front end::

    i_measured = G(s) * [H_i(s) / H_v(s)] * v_measured

so a known front end is modelled exactly by passing the measured voltage
through ``H_i/H_v`` before the winding model. This module describes front ends
(:class:`FrontEnd`, :func:`parse_front_end`) and applies the relative one to a
window of samples (:func:`apply_relative`).

Filter sections are ``(kind, w0, Q)`` rows: ``kind`` 1 is ``w0/(s + w0)``,
``kind`` 2 is ``w0^2/(s^2 + (w0/Q)s + w0^2)``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from observer.config import FILTER_KINDS, MAX_FILTER_ORDER, parse_filter

__all__ = ["FILTER_KINDS", "MAX_FILTER_ORDER", "FrontEnd", "parse_filter"]

# Bessel (maximally flat delay) sections normalised to -3 dB at 1 rad/s: (w0, Q) per
# section, Q = 0 marks a first-order section (the poles of scipy.signal.bessel(N, 1, norm="mag")).
_BESSEL: dict[int, tuple[tuple[float, float], ...]] = {
    1: ((1.0, 0.0),),
    2: ((1.2720196495140679, 0.5773502691896257),),
    3: ((1.3226757999104441, 0.0), (1.4476171331469865, 0.6910466258250713)),
    4: ((1.4301715599939884, 0.5219345816689802), (1.6033575162169704, 0.8055382818416656)),
}


def filter_sections(kind: str, order: int, cutoff_hz: float | None) -> np.ndarray:
    """Sections ``(kind, w0, Q)`` of a low pass with its -3 dB point at ``cutoff_hz``.

    At most two sections (order <= 4); rows of zeros are empty.
    """
    out = np.zeros((2, 3))
    if kind == "none" or order == 0:
        return out
    if cutoff_hz is None or not cutoff_hz > 0:
        raise ValueError(f"a {kind} filter needs a cutoff > 0 Hz")
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
        # n equal stages with the cascade's -3 dB point at wc; two equal first-order
        # stages are one second-order section with Q = 1/2.
        stage = 1.0 / math.sqrt(2.0 ** (1.0 / order) - 1.0)
        secs = [(stage, 0.5)] * (order // 2)
        if order % 2:
            secs.append((stage, 0.0))
    else:
        raise ValueError(f"unknown filter {kind!r} (expected {', '.join(FILTER_KINDS)})")
    for i, (w0, q) in enumerate(secs):
        out[i] = (1.0 if q == 0.0 else 2.0, w0 * wc, q)
    return out


def sections_response(sections: np.ndarray, f_hz: np.ndarray) -> np.ndarray:
    """Complex response of filter ``sections`` at frequencies ``f_hz``."""
    s = 2j * math.pi * np.asarray(f_hz, dtype=float)
    h = np.ones_like(s)
    for kind, w0, q in sections:
        if kind == 1:
            h = h * w0 / (s + w0)
        elif kind == 2:
            h = h * w0 * w0 / (s * s + (w0 / q) * s + w0 * w0)
    return h


@dataclass(frozen=True)
class FrontEnd:
    """One channel's measurement front end.

    Attributes
    ----------
    filter : {"none", "butter", "bessel", "rc"}
    order : int
        0 with ``none``, else 1..4.
    cutoff_hz : float or None
        -3 dB frequency (Hz) of the filter.
    cutoff_per_fs : float or None
        The same as a fraction of the sample rate (0.25 = fs/4); at most one of the two.
    delay_s : float
        Sampling instant after the nominal one (s).
    averaging : bool
        The sample is the filtered signal's mean over the period ending at its instant.
    """

    filter: str = "none"
    order: int = 0
    cutoff_hz: float | None = None
    cutoff_per_fs: float | None = None
    delay_s: float = 0.0
    averaging: bool = False

    def cutoff_at(self, sample_rate_hz: float) -> float | None:
        if self.cutoff_hz is not None:
            return self.cutoff_hz
        if self.cutoff_per_fs is not None:
            return self.cutoff_per_fs * sample_rate_hz
        return None

    def response(self, f_hz: np.ndarray, sample_rate_hz: float) -> np.ndarray:
        """Complex response at ``f_hz`` (Hz): filter, sampling delay and averaging."""
        f = np.asarray(f_hz, dtype=float)
        h = sections_response(
            filter_sections(self.filter, self.order, self.cutoff_at(sample_rate_hz)), f
        )
        # Sampled ``delay_s`` after the nominal instant, the sample holds the signal of that
        # later instant: an advance, ``exp(+j w delay)``, on the nominal grid.
        h = h * np.exp(2j * math.pi * f * self.delay_s)
        if self.averaging:
            period = 1.0 / sample_rate_hz
            # Mean over the period ending at the instant: delay T/2, sinc amplitude.
            h = h * np.exp(-1j * math.pi * f * period) * np.sinc(f * period)
        return h

    @property
    def is_plain(self) -> bool:
        """No filter, no delay, no averaging: the instantaneous value."""
        return self.filter == "none" and self.delay_s == 0.0 and not self.averaging


def parse_front_end(text: str, *, delay_s: float = 0.0, averaging: bool = False) -> FrontEnd:
    """A :class:`FrontEnd` from ``parse_filter`` text plus delay and averaging."""
    fields = parse_filter(text)
    return FrontEnd(delay_s=delay_s, averaging=averaging, **fields)


def from_config(channel: Any) -> FrontEnd | None:
    """The :class:`FrontEnd` of a :class:`observer.config.ChannelFrontEnd`, or None if unknown."""
    if channel is None or channel.filter is None:
        return None
    return parse_front_end(
        channel.filter, delay_s=channel.delay_us * 1e-6, averaging=channel.averaging
    )


#: Each winding's voltage and current channels, by their config field names.
WINDING_CHANNELS = {"field": ("vf", "i_f"), "armature": ("va", "ia")}


def winding_front_ends(chain: Any, winding: str) -> tuple[FrontEnd, FrontEnd] | None:
    """``(voltage, current)`` front ends of a winding when the chain config knows both."""
    if chain is None:
        return None
    v_name, i_name = WINDING_CHANNELS[winding]
    fe_v = from_config(getattr(chain, v_name))
    fe_i = from_config(getattr(chain, i_name))
    if fe_v is None or fe_i is None:
        return None
    return fe_v, fe_i


def gain_tolerances(chain: Any, winding: str) -> dict[str, float]:
    """Each of ``winding``'s parameters' relative one-sigma from its sensors' configured
    ``gain_tolerance`` (0 where none is configured).

    A sensor's gain error scales what the fit sees, and no window can tell it from the motor:
    ``R`` and ``L`` come out scaled by the voltage's gain over the current's, the armature's
    ``K`` (in ``va = Ra ia + La dia/dt + K if omega``) by the armature voltage's over the
    field current's and the speed's.
    """
    if chain is None:
        return {}

    def tol(*names: str) -> float:
        return math.sqrt(sum(getattr(chain, n).gain_tolerance ** 2 for n in names))

    v_name, i_name = WINDING_CHANNELS[winding]
    out = {"R": tol(v_name, i_name), "L": tol(v_name, i_name)}
    if winding == "armature":
        out["K"] = tol("va", "i_f", "omega")
    return {k: v for k, v in out.items() if v > 0}


def voltage_filtered(front_ends: tuple[FrontEnd, FrontEnd] | None) -> bool:
    """The configured voltage front end of ``(voltage, current)`` has an anti-aliasing
    filter (False where the front ends are not configured)."""
    return front_ends is not None and front_ends[0].filter != "none" and front_ends[0].order > 0


def check_against_rate(fe: FrontEnd, sample_rate_hz: float, key: str) -> None:
    """Raise ValueError naming ``key`` if ``fe`` cannot hold at ``sample_rate_hz``."""
    cutoff = fe.cutoff_at(sample_rate_hz)
    if cutoff is not None and cutoff >= sample_rate_hz / 2:
        raise ValueError(
            f"{key}: cutoff {cutoff:g} Hz is at or above the Nyquist frequency "
            f"{sample_rate_hz / 2:g} Hz of {sample_rate_hz:g} Hz sampling"
        )
    if not 0.0 <= fe.delay_s < 1.0 / sample_rate_hz:
        raise ValueError(f"{key}: delay must be >= 0 and below one sample period")


def relative_response(
    voltage: FrontEnd, current: FrontEnd, f_hz: np.ndarray, sample_rate_hz: float
) -> np.ndarray:
    """``H_i(f)/H_v(f)``: the current channel's front end relative to the voltage channel's."""
    return current.response(f_hz, sample_rate_hz) / voltage.response(f_hz, sample_rate_hz)


def apply_relative(v: np.ndarray, dt: float, voltage: FrontEnd, current: FrontEnd) -> np.ndarray:
    """Measured voltage samples seen through the current channel's front end instead of their own.

    The window is mirror-extended (so its periodic continuation has no jump)
    and filtered by ``H_i/H_v`` in the frequency domain, exact for a
    band-limited voltage. The first and last few samples carry the extension's
    error; callers leave them out (:func:`edge_samples`).
    """
    n = v.shape[0]
    if n < 4:
        return np.array(v, dtype=np.float64)
    ext = np.concatenate([v, v[-2:0:-1]])
    f = np.fft.rfftfreq(ext.shape[0], dt)
    spec = np.fft.rfft(ext) * relative_response(voltage, current, f, 1.0 / dt)
    out: np.ndarray = np.fft.irfft(spec, ext.shape[0])[:n]
    return out


def edge_samples(voltage: FrontEnd, current: FrontEnd, dt: float) -> int:
    """Samples at each end of a window that :func:`apply_relative` may spoil."""
    taus = []
    for fe in (voltage, current):
        sections = filter_sections(fe.filter, fe.order, fe.cutoff_at(1.0 / dt))
        for kind, w0, q in sections:
            if kind:
                taus.append((2.0 * q if kind == 2 else 1.0) / w0)
    tau = max(taus, default=0.0)
    return int(math.ceil(6.0 * tau / dt)) + 2


#: Where a winding's front ends are not configured, the relative gain of its two channels
#: is taken as unknown up to that of the commonest mismatch: a first-order filter on one
#: channel beside a second-order Butterworth on the other, both at fs/4 (a voltage
#: divider's RC beside a current transducer's active filter). At a 6-pulse bridge's 300 Hz
#: the pair differs in gain by 9.7 % at 2 kHz, 2.7 % at 5 kHz and 0.7 % at 10 kHz, which
#: ``La`` takes whole.
UNKNOWN_MISMATCH = ("rc1@fs/4", "butter2@fs/4")


#: Pairs whose shapes the data is asked about where the front ends are untold
#: (:func:`observer.estimation.stages.std_stage`): the commonest, a 4th-order Bessel beside
#: the 2nd-order Butterworth (its gain falls earlier and rounder), and one channel filtered
#: at half the other's cutoff. Between them they span how two low-pass front ends can
#: differ at a converter's ripple: a gain that falls with frequency at different rates.
MISMATCH_SHAPES = (
    UNKNOWN_MISMATCH,
    ("bessel4@fs/4", "butter2@fs/4"),
    ("butter2@fs/8", "butter2@fs/4"),
)

#: A mismatch's size as the window measures it (projected on a shape of
#: :data:`MISMATCH_SHAPES`, beside the fitted parameters and the delay) moves ``L`` by less
#: than the mismatch does: the fit and the delay take up part of it, and the real pair's
#: shape is none of the three. On the P-12 behind a 6-pulse bridge (30 s at 2 and 5 kHz,
#: untold; RC voltages, RC currents, 4th-order Bessel currents, 2nd-order Bessel voltages,
#: voltages filtered at fs/8), ``La``'s error was 0.36-1.41 times the largest move a measured
#: size implied; the measured part is counted twice.
MISMATCH_UNDERSEEN = 2.0


def unknown_mismatch(
    v: np.ndarray, dt: float, pair: tuple[str, str] = UNKNOWN_MISMATCH
) -> np.ndarray:
    """The change of voltage samples were the channels the pair (default
    :data:`UNKNOWN_MISMATCH`).

    ``v`` seen through ``H_b/H_a`` instead of unchanged, less the pair's
    relative delay (the fitted or learned shift takes that): the shape of the
    mismatch alone, its gain and phase away from zero frequency. The window is
    mirror-extended as in :func:`apply_relative`.
    """
    n = v.shape[0]
    if n < 4:
        return np.zeros(n)
    ext = np.concatenate([v, v[-2:0:-1]])
    shape = _mismatch_shape(ext.shape[0], float(dt), pair)
    out: np.ndarray = np.fft.irfft(np.fft.rfft(ext) * shape, ext.shape[0])[:n]
    return out


def mismatch_response(pair: tuple[str, str], dt: float) -> Callable[[int], np.ndarray]:
    """The change :func:`unknown_mismatch` makes, as a gain at the real FFT's bins of an
    extension of ``n`` samples (for
    :func:`~observer.estimation.intersample.smooth_moments_through`)."""
    return functools.partial(_mismatch_shape, dt=float(dt), pair=pair)


@functools.lru_cache(maxsize=32)
def _mismatch_shape(n: int, dt: float, pair: tuple[str, str]) -> np.ndarray:
    """``H_b/H_a`` less its delay, minus one, at the real FFT's bins of ``n`` samples (a
    window's length repeats: cached, read-only)."""
    a, b = (parse_front_end(text) for text in pair)
    fs = 1.0 / dt
    f0 = 1e-4 * fs
    delay = -float(np.angle(relative_response(a, b, np.array([f0]), fs)[0])) / (2 * math.pi * f0)
    f = np.fft.rfftfreq(n, dt)
    shape: np.ndarray = relative_response(a, b, f, fs) * np.exp(2j * math.pi * f * delay) - 1.0
    shape.flags.writeable = False
    return shape


#: An untold mismatch of the commonest pair's shape (:data:`UNKNOWN_MISMATCH`) learned from
#: the first windows or from a whole recording (its size fitted with the voltage's delay)
#: is corrected for from this size on; a smaller one stays in the std. On channels filtered
#: alike the size learned is 0.03 at 5 kHz and 0.12 at 2 kHz, where the converter's folded
#: content leans on it: corrected, La would move 1.2 % for nothing.
MISMATCH_APPLIED = 0.3

#: The share of an applied correction that stays uncertain, beside what the window still
#: measures: the real pair's shape need not be the commonest one's (corrected, a 4th-order
#: Bessel current filter's La error fell by a third to four fifths, a voltage filtered at fs/8
#: at 5 kHz turned from -3.3 % to +2 %).
MISMATCH_SHAPE = 0.5


def applied_mismatch(learned: float | None) -> float:
    """The size (units of :data:`UNKNOWN_MISMATCH`) a window's voltage is corrected by, from
    the size learned (None: none learned); 0 below :data:`MISMATCH_APPLIED`."""
    if learned is None or not math.isfinite(learned) or abs(learned) < MISMATCH_APPLIED:
        return 0.0
    return float(learned)
