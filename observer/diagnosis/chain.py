"""What the measurement chain, not the motor, leaves in a recording: front-end findings.

A converter's voltage is not band-limited: its harmonics run far beyond the
Nyquist frequency, and what the anti-aliasing filter lets through above it
folds back into the samples. A band-limited reconstruction of the voltage
between samples (the estimator's ``smooth`` model) is then wrong by the folded
part, and the part folded onto zero frequency (harmonics at multiples of the
sample rate) is a slow voltage error that follows the converter's firing angle
and so the operating point: structure the motor does not cause. It cannot be
seen in the samples (that is what aliasing means), but it can be bounded from
what *can* be seen: the voltage's line content just below the Nyquist
frequency and how fast it falls there, extrapolated to the sample rate
(:func:`voltage_spectrum`).

Three findings come from the front end alone, whatever the motor does:

``no_anti_aliasing``
    The voltage's line content does not fall towards the Nyquist frequency
    (no filter, or one far above it). Judged on a bridge's comb of harmonics; a line
    standing alone near Nyquist (a chopper's pulses) says nothing of the filter, and a
    chopper sampled bare is ``pwm_sampled_bare``.
``channel_skew``
    The estimator's fitted relative delay between the voltage and current
    channels is significant: different filters on the two channels, or a
    multiplexed ADC sampling them one after another.
``content_near_nyquist``
    Structure located in the residual is no larger than the folded voltage
    could cause (decided in :mod:`observer.diagnosis.diagnose`).
``front_ends_unknown``
    The winding's front ends are not configured, and a mismatch of the voltage
    and current channels' filters that the samples leave room for would move its
    inductance by more than :data:`FRONT_END_SHARE` (the estimate's ``front_end_std``).
``pwm_sampled_bare``
    The voltage's samples sit at a PWM converter's levels and change level in
    many intervals: a chopper's terminals sampled without a filter, whose
    samples do not show the duty cycle
    (:func:`~observer.estimation.intersample.pwm_level_changes`). The
    estimator then describes no window of that winding, and no motor effect
    can be judged from it.
``pulses_aliased``
    The armature's voltage and current carry a line the current does not answer as the
    winding would at that frequency (a chopper's pulses above the Nyquist frequency, seen at
    their alias: 4 kHz sampled at 5 kHz reads 1 kHz); the estimator and the diagnosis leave
    that band out (:mod:`observer.estimation.lines`).
``pulses_folded``
    The armature's voltage reading is off by a curve periodic in the voltage: a converter's
    pulse harmonic on a multiple of the sample rate (a 2 kHz chopper's 4 kHz pulses at 10
    kHz: the 5th on 2 fs), folded onto zero frequency by a filter that leaves a little of
    it (:class:`~observer.estimation.linearity.Fold`). Small enough to be fitted; the
    estimator and the diagnosis take it out of the reading.
``voltage_folded``
    The armature's voltage samples follow a curve of the voltage, not the voltage: a
    converter's pulses sampled in step with the ADC fold onto zero frequency
    (:mod:`observer.estimation.linearity`). The estimator holds the armature, and no
    armature effect is judged from it.
``pulses_locked``
    The armature's converter jumps keep their place between samples over most of the
    recording (the sample rate a whole multiple of the pulse rate: 3 or 6 kHz behind a 6-pulse
    bridge on 50 Hz mains): their alias through the filter errs every sample alike, a slow
    error of the voltage that follows the firing angle and that no window averages away
    (:func:`~observer.estimation.intersample.alias_bias`). The estimator widens the armature's
    std for it; armature effects of that size cannot be judged.
``current_filtered_apart``
    The voltage was sampled without a filter (clean jumps) and the current
    through one: the current's bend after every jump rings out over the
    current filter's response
    (:func:`~observer.estimation.intersample.current_settling`), samples the
    estimator then leaves out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from observer.diagnosis.results import ChainFinding
from observer.estimation.intersample import (
    PWM_CHANGES,
    alias_bias,
    current_settling,
    find_switching,
    jump_runs,
    pwm_level_changes,
)
from observer.estimation.linearity import Fold, Linearity

#: Line content in the top eighth-band below Nyquist at least this share of the one below
#: it: the spectrum does not fall towards Nyquist (a filter of order n at fs/4 gives about
#: 0.7^(n+1) here with a converter's 1/h harmonics: 0.35 for a 2nd-order one).
FLAT_RATIO = 0.65
#: ... and over two octaves, the top eighth-band at least this share of ``[fs/8, fs/4)``.
#: Where the comb is sparse (a 6-pulse bridge's 300 Hz lines at 4 kHz: one line in the band
#: below, two in the top one) the neighbouring bands' ratio counts lines, not a fall: behind
#: 2nd-order Butterworths at fs/4 the P-12's and the 440 V motor's armature read 0.68-0.69 at
#: 4 kHz, as much as no filter at 3.5 kHz. Over the wider span, with more lines on each side,
#: no filter keeps 0.38-0.68 (both motors, 2-10 kHz; 20 seeds at 2, 5, 10 kHz, one at 8 more
#: rates), those Butterworths 0.09-0.27; an RC at fs/4 0.10-0.43.
FLAT_WIDE_RATIO = 0.3
#: ... and at least this share of the voltage's standard deviation (not the noise of a
#: drive that changes its held voltage every sample).
FLAT_MIN_SHARE = 0.01
#: Top band's content this many times the band below it: not a comb that fails to fall but a
#: line that stands alone near Nyquist (a chopper's pulses, 4 kHz at 10 kHz, or their
#: alias). A bridge's harmonics fall as 1/h, and with no filter at all their aliases keep
#: the two bands within 0.65-0.9 of each other (P-12, 50 and 60 Hz, 2-10 kHz); a filtered
#: chopper's pulse line stands 5-1200 times above the band below. The fall cannot say
#: whether such a line was filtered: a chopper sampled bare is ``pwm_sampled_bare``.
LINE_RATIO = 2.5
#: A fitted relative delay (sample periods) this large, and ...
SKEW_MIN_SAMPLES = 0.02
#: ... this many of its standard deviations, is a chain finding.
SKEW_SIGMAS = 4.0

#: An untold front end that could move L by more than this share is a chain finding.
FRONT_END_SHARE = 0.01

#: Band edges (fractions of the sample rate) of the line content compared.
_LOW = (0.125, 0.25)
_MID = (0.25, 0.375)
_TOP = (0.375, 0.5)

#: Share of the armature voltage's seconds whose jumps are locked to the samples beyond which
#: the recording is ``pulses_locked`` (the 440 V motor behind a 6-pulse bridge at 3 and 6 kHz:
#: 5 of 6 seconds, the error of a second's mean voltage 0.3-0.57 V against 0.02-0.03 V at 2,
#: 4 and 5 kHz, and the plain model's ia residual 0.34 A at 3 kHz against 0.07 A at 5 kHz).
LOCKED_SHARE = 0.5
LOCKED_ADVICE = (
    "sample at a rate that is not a whole multiple of the converter's pulse rate (behind a "
    "6-pulse bridge not 3, 6 or 9 kHz on 50 Hz mains, nor 3.6 or 7.2 kHz on 60 Hz), or "
    "measure the voltage averaged over each period; configure the converter and chain in "
    "[chain]"
)

NO_FILTER_ADVICE = (
    "add an anti-aliasing filter at or below fs/4 to the {ch} channel, or measure it averaged "
    "over each period, or sample faster, and configure it in [chain.{ch}]"
)
SKEW_ADVICE = (
    "configure the front ends in [chain] (filter of each channel, delay_us of a multiplexed ADC) "
    "or filter the voltage and current channels alike"
)
AVERAGED_ADVICE = (
    "nothing is needed for the estimate; configure it as [chain.{ch}] averaging = true so "
    "the estimator models the mean instead of fitting a delay"
)
FRONT_END_ADVICE = (
    "configure the {ch} and {cur} channels' front ends in [chain] (filter kind, order and "
    "cutoff of each): the estimator then models them exactly"
)
PWM_ADVICE = (
    "filter the {ch} channel (an anti-aliasing filter at or below fs/4, well below the carrier) "
    "or measure it averaged over each sample period, and configure it in [chain.{ch}]"
)
CURRENT_FILTER_ADVICE = (
    "give the {ch} channel the {cur} channel's anti-aliasing filter (which also keeps the "
    "converter's jumps from folding into its samples), or sample faster, and configure both in "
    "[chain.{ch}] and [chain.{cur}]"
)
PULSES_LINE_ADVICE = (
    "measure {ch} averaged over each sample period (an integrating ADC), or filter it more "
    "steeply below the converter's pulse frequency, and configure it in [chain.{ch}]"
)
ALIAS_ADVICE = (
    "sample faster (at least 5 kHz behind a 6-pulse bridge), or lower the voltage channels' "
    "anti-aliasing cutoff, or measure the voltages averaged over each period; configure the "
    "converter and chain in [chain]"
)


@dataclass(frozen=True)
class VoltageSpectrum:
    """A voltage channel's line content near the Nyquist frequency.

    Attributes
    ----------
    noise_v : float
        RMS (V) of the flat floor (noise) over the band from 0 to Nyquist.
    mid_v, top_v : float
        RMS (V) of the content above that floor in ``[fs/4, 3fs/8)`` and ``[3fs/8, fs/2)``.
    low_v : float
        The same in ``[fs/8, fs/4)``.
    alias_v : float
        Line amplitude (V) extrapolated to the sample rate: a bound on the slow
        voltage error that folding can put into the samples.
    std_v : float
        Standard deviation of the voltage (V).
    """

    noise_v: float
    mid_v: float
    top_v: float
    alias_v: float
    std_v: float
    low_v: float = 0.0

    @property
    def ratio(self) -> float:
        """Top band against the band below it: how far the content falls towards Nyquist."""
        return self.top_v / self.mid_v if self.mid_v > 0 else 0.0

    @property
    def line(self) -> bool:
        """Whether the top band holds a line standing alone (:data:`LINE_RATIO`), not a comb."""
        return self.ratio >= LINE_RATIO

    @property
    def flat(self) -> bool:
        """Whether a comb's content does not fall towards Nyquist (no anti-aliasing filter)."""
        return (
            FLAT_RATIO <= self.ratio < LINE_RATIO
            and self.top_v >= FLAT_WIDE_RATIO * self.low_v
            and self.top_v >= FLAT_MIN_SHARE * self.std_v
        )


def _welch(v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density (V^2/Hz) by Welch's method, Hann windows, 50 % overlap."""
    x = np.asarray(v, dtype=np.float64)
    x = x[np.isfinite(x)]
    m = int(2 ** math.floor(math.log2(max(x.size // 4, 64))))
    m = min(m, 2048)
    window = np.hanning(m)
    step = m // 2
    starts = range(0, x.size - m + 1, step)
    t = np.arange(m) - (m - 1) / 2
    acc = np.zeros(m // 2 + 1)
    count = 0
    for s in starts:
        seg = x[s : s + m]
        slope = float(t @ seg) / float(t @ t)
        seg = seg - seg.mean() - slope * t
        acc += np.abs(np.fft.rfft(seg * window)) ** 2
        count += 1
    psd = acc / max(count, 1) * dt / float(window @ window)
    psd[1:-1] *= 2.0
    return np.fft.rfftfreq(m, dt), psd


def voltage_spectrum(v: np.ndarray, dt: float) -> VoltageSpectrum:
    """The line content of voltage ``v`` near Nyquist and what can fold onto low frequencies.

    The floor is the smallest of the median densities of the 14 bands of width
    ``fs/32`` from ``fs/16`` to Nyquist (a converter's lines are sparse, so a
    band's median is its floor); a band's content is its power above that
    floor. The content of ``[3fs/8, fs/2)`` falls from that of
    ``[fs/4, 3fs/8)`` by a ratio ``q``; continued at the same rate, a line at
    the sample rate has ``top * q^k`` with ``k = ln(fs/f_top)/ln(f_top/f_mid)``
    (band centres): the folded error is bounded by that.

    A line standing alone in the top band (:data:`LINE_RATIO`: a chopper's pulses) is no
    such comb, and continued it would bound nothing (the P-12 behind a filtered chopper at
    10 kHz: a 31 V line, where the error the pulses fold onto the reading is 0.28 V rms,
    measured and taken out by the armature's fold fit, ``pulses_folded``). The spectrum then
    vouches for no folded error: ``alias_v`` is 0, and a motor effect is not put down to it
    (it had taken a 2 % thermal rise and a back-EMF ripple for the chain's).
    """
    f, psd = _welch(v, dt)
    fs = 1.0 / dt
    df = float(f[1] - f[0])
    edges = np.linspace(fs / 16, fs / 2, 15)
    medians = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        band = (f >= lo) & (f < hi)
        medians.append(float(np.median(psd[band])) if band.any() else math.inf)
    floor = min(medians)

    def content(lo_share: float, hi_share: float) -> float:
        band = (f >= lo_share * fs) & (f < hi_share * fs)
        return math.sqrt(max(float(np.sum(psd[band] - floor)) * df, 0.0))

    mid, top = content(*_MID), content(*_TOP)
    alias = 0.0
    if mid > 0 and top > 0 and top < LINE_RATIO * mid:
        f_mid, f_top = sum(_MID) / 2, sum(_TOP) / 2
        k = math.log(1.0 / f_top) / math.log(f_top / f_mid)
        alias = top * min(top / mid, 1.0) ** k
    x = np.asarray(v, dtype=np.float64)
    return VoltageSpectrum(
        noise_v=math.sqrt(floor * fs / 2),
        mid_v=mid,
        top_v=top,
        alias_v=alias,
        std_v=float(np.nanstd(x)),
        low_v=content(*_LOW),
    )


def no_filter_finding(channel: str, spectrum: VoltageSpectrum) -> ChainFinding | None:
    """``no_anti_aliasing`` if the voltage's content does not fall towards Nyquist."""
    if not spectrum.flat:
        return None
    return ChainFinding(
        channel,
        "no_anti_aliasing",
        f"measurement chain: {channel} has as much converter content just below the Nyquist "
        f"frequency as a band lower ({spectrum.top_v:.3g} V against {spectrum.mid_v:.3g} V): "
        "it was sampled without an anti-aliasing filter, or with one too weak or too high for this "
        "sample rate, so what the "
        "converter does between samples is not in the samples",
        NO_FILTER_ADVICE.format(ch=channel),
    )


def locked_finding(
    channel: str, v: np.ndarray, dt: float, factor: Callable[[], float]
) -> ChainFinding | None:
    """``pulses_locked`` if the converter's jumps in ``v`` keep their place between samples in
    more than :data:`LOCKED_SHARE` of its seconds; ``factor`` gives the voltage filter's
    aliasing factor (:func:`~observer.estimation.intersample.alias_factor`), which sizes the
    error (asked only where the jumps are locked: identifying the filter takes seconds)."""
    v = np.asarray(v, dtype=np.float64)
    n = max(int(round(1.0 / dt)), 64)
    sizes, periods, pieces = [], [], 0
    for start in range(0, v.shape[0] - n // 2, n):
        piece = v[start : start + n]
        if not np.all(np.isfinite(piece)):
            continue
        pieces += 1
        transitions = find_switching(piece, dt).transition_mask
        size, locked = alias_bias(piece, transitions, 1.0)
        if locked:
            sizes.append(size)
            periods.append(float(np.median(np.diff(jump_runs(piece, transitions)[0]))))
    if not pieces or len(sizes) <= LOCKED_SHARE * pieces:
        return None
    period = float(np.median(periods))
    scale = factor()
    sizes = [scale * x for x in sizes]
    return ChainFinding(
        channel,
        "pulses_locked",
        f"measurement chain: {channel}'s converter jumps keep their place between samples in "
        f"{len(sizes)} of its {pieces} seconds (one every {period:.3g} samples: the sample "
        f"rate is a whole multiple of their {1.0 / (period * dt):.4g} Hz), so their alias "
        "through the front end errs every sample alike: a slow error of the voltage that "
        f"follows the firing angle, up to {max(sizes):.2g} V in a second's mean (median "
        f"{float(np.median(sizes)):.2g} V), which no window averages away; the estimator "
        "widens the armature's std for it, and armature effects of that size cannot be judged",
        LOCKED_ADVICE,
    )


def skew_finding(
    voltage: str, current: str, shift_samples: float, shift_std: float, dt: float
) -> ChainFinding | None:
    """``channel_skew`` if the fitted relative delay of ``voltage`` behind ``current`` is real."""
    size = abs(shift_samples)
    if size < SKEW_MIN_SAMPLES or size < SKEW_SIGMAS * shift_std:
        return None
    late, early = (voltage, current) if shift_samples > 0 else (current, voltage)
    return ChainFinding(
        voltage,
        "channel_skew",
        f"measurement chain: {late} reads {1e6 * size * dt:.3g} us ({size:.3f} sample periods, "
        f"+-{shift_std:.2g}) behind {early} (fitted by the estimator): the two channels have "
        "different anti-aliasing filters or are sampled one after another",
        SKEW_ADVICE,
    )


def averaged_finding(voltage: str, current: str, shift_samples: float) -> ChainFinding:
    """``voltage_averaged``: an untold voltage channel that reads as its mean over each period."""
    return ChainFinding(
        voltage,
        "voltage_averaged",
        f"measurement chain: {voltage} reads as the voltage averaged over each sample period "
        f"(an integrating ADC), half a period behind {current} ({shift_samples:.3f} sample "
        "periods fitted as a delay); the mean over each period, with no delay, describes the "
        "armature's converter ripple better than any delay: the baseline is fitted so",
        AVERAGED_ADVICE.format(ch=voltage),
    )


def alias_finding(
    channel: str, spectrum: VoltageSpectrum, offset_v: float, words: str
) -> ChainFinding:
    """``content_near_nyquist``: located structure no larger than folding can cause."""
    if spectrum.line:
        # A chopper's pulses: the bound is the fold fitted on the armature's reading.
        return ChainFinding(
            channel,
            "content_near_nyquist",
            f"measurement chain: {channel} carries a converter's pulse line near the Nyquist "
            f"frequency ({spectrum.top_v:.3g} V in the top eighth-band), whose harmonics on "
            f"multiples of the sample rate fold onto the reading as a curve periodic in the "
            f"voltage of up to {spectrum.alias_v:.3g} V (from the fold fitted on the armature's "
            f"reading); the structure located ({words}, {offset_v:.3g} V at the winding) is no "
            "larger: it is the sampling of the converter's pulses, not the motor",
            PULSES_LINE_ADVICE.format(ch=channel),
        )
    return ChainFinding(
        channel,
        "content_near_nyquist",
        f"measurement chain: {channel} carries converter content up to the Nyquist frequency "
        f"({spectrum.top_v:.3g} V in the top eighth-band), whose folded part can shift the "
        f"voltage by up to {spectrum.alias_v:.3g} V with the firing angle; the structure "
        f"located ({words}, {offset_v:.3g} V at the winding) is no larger: it is the sampling "
        "of the converter's voltage, not the motor",
        ALIAS_ADVICE,
    )


def front_end_finding(
    voltage: str, current: str, front_end_std: float, inductance: float, name: str
) -> ChainFinding | None:
    """``front_ends_unknown`` if untold front ends leave ``L`` (``name``) this uncertain."""
    share = front_end_std / inductance if inductance > 0 else 0.0
    if not share > FRONT_END_SHARE:
        return None
    return ChainFinding(
        voltage,
        "front_ends_unknown",
        f"measurement chain: the {voltage} and {current} front ends are not configured, and the "
        f"samples leave room for anti-aliasing filters of different kinds that would put {name} "
        f"off by {100 * share:.1f} %: the relative gain at the converter's ripple scales the "
        "ripple current, and the samples tell it only in part",
        FRONT_END_ADVICE.format(ch=voltage, cur=current),
    )


def current_filter_finding(
    voltage: str, current: str, v: np.ndarray, i: np.ndarray, dt: float | None = None
) -> ChainFinding | None:
    """``current_filtered_apart`` if ``i`` rings out after ``v``'s clean jumps (``dt``: the
    sample period, see :func:`~observer.estimation.intersample.find_switching`)."""
    sw = find_switching(v, dt)
    if not sw.switched:
        return None
    settle = current_settling(i, v, sw)
    if settle == 0:
        return None
    share = sw.widened(settle).transition_share - sw.transition_share
    return ChainFinding(
        voltage,
        "current_filtered_apart",
        f"measurement chain: {voltage} was sampled without an anti-aliasing filter (a clean jump "
        f"at every firing) and {current} through one: the current's bend after each jump rings "
        f"out over {settle} samples, which the estimator leaves out ({100 * share:.0f} % of the "
        "samples); the two channels do not see the converter alike",
        CURRENT_FILTER_ADVICE.format(ch=voltage, cur=current),
    )


#: Advice of a chain finding of kind ``pulses_aliased``.
ALIASED_ADVICE = (
    "sample at more than twice the converter's pulse frequency, or filter the {ch} and {cur} "
    "channels well below it, or measure {ch} averaged over each period, and configure the "
    "chain in [chain]"
)


def aliased_finding(
    voltage: str, current: str, bands: list[tuple[float, float]]
) -> ChainFinding | None:
    """``pulses_aliased`` for the ``bands`` (Hz) of the voltage's lines that the current does
    not answer as the winding would (:func:`~observer.estimation.lines.aliased_lines`)."""
    if not bands:
        return None
    lines = ", ".join(f"{0.5 * (lo + hi):.0f} Hz" for lo, hi in bands)
    return ChainFinding(
        voltage,
        "pulses_aliased",
        f"measurement chain: {voltage} and {current} carry a line at {lines} that the current "
        "does not answer as the winding would at that frequency: a converter's pulses above the "
        "Nyquist frequency, seen at their alias; the band was left out of the estimate and of "
        "the diagnosis",
        ALIASED_ADVICE.format(ch=voltage, cur=current),
    )


def pulses_folded_finding(channel: str, fold: Fold | None) -> ChainFinding | None:
    """``pulses_folded`` for the ``fold`` taken out of ``channel`` (None: none was)."""
    if fold is None:
        return None
    return ChainFinding(
        channel,
        "pulses_folded",
        f"measurement chain: {channel} is off by a curve periodic in the voltage (period "
        f"{fold.period_v:.0f} V, {fold.rms_v:.2g} V rms, {100 * fold.share:.0f} % of the slow "
        "error of the winding's equation): a converter's pulse harmonic on a multiple of the "
        "sample rate, folded onto zero frequency; it was taken out of the reading before the "
        "estimate and the diagnosis",
        PULSES_FOLDED_ADVICE.format(ch=channel),
    )


def pulses_bound_finding(channel: str, spectrum: VoltageSpectrum) -> ChainFinding:
    """``pulses_folded`` on a ``channel`` whose residual the fold's bound (``alias_v``, the
    armature's fold scaled to it) excuses: its pulses fold alike, and were not taken out (or
    only as far as the bound says)."""
    return ChainFinding(
        channel,
        "pulses_folded",
        f"measurement chain: {channel} is fed by a converter's pulses ({spectrum.top_v:.3g} V "
        "of their line in the top eighth-band) that fold onto its reading by up to "
        f"{spectrum.alias_v:.3g} V (the fold fitted on the armature's reading"
        + (", scaled to this voltage" if channel != "va" else "")
        + "; a winding at a few steady levels reads one offset per level, which no curve "
        "shows), and what that leaves in the residual is not the motor's",
        PULSES_LINE_ADVICE.format(ch=channel),
    )


#: Advice of a chain finding of kind ``pulses_folded``.
PULSES_FOLDED_ADVICE = (
    "nothing is needed for the estimate; to read {ch} without the fold, measure it averaged over "
    "each sample period (an integrating ADC) or filter it more steeply, and configure it in "
    "[chain.{ch}]"
)


#: Advice of a chain finding of kind ``voltage_folded``.
FOLDED_ADVICE = (
    "sample at a rate that is not a multiple of half the converter's pulse frequency (behind a "
    "2 kHz carrier's 4 kHz pulses, 5 or 10 kHz rather than 2, 4 or 8 kHz), or measure {ch} "
    "averaged over each sample period, and configure it in [chain.{ch}]"
)


def folded_finding(channel: str, result: Linearity | None) -> ChainFinding | None:
    """``voltage_folded`` if the linearity test ``result`` of ``channel`` found a curve."""
    if result is None or result.linear:
        return None
    return ChainFinding(
        channel,
        "voltage_folded",
        f"measurement chain: {channel}'s samples follow a curve of the voltage "
        f"({result.curve_v:.2g} V rms, {100 * result.size:.2g} % of the "
        f"largest, explains {100 * result.share:.0f} % of the slow error of the winding's "
        "equation): a converter's pulses sampled in step with the ADC, folded onto zero "
        "frequency, read as a gain and a curve that no model of the samples takes out; the "
        "winding is not estimated from it, and no effect on it judged",
        FOLDED_ADVICE.format(ch=channel),
    )


def field_folded_finding(channel: str, note: str) -> ChainFinding | None:
    """``voltage_folded`` on the field's ``channel`` judged beside a folded armature: ``note``
    is :func:`~observer.estimation.linearity.field_note`'s reason ("" where the field can be
    described)."""
    if not note:
        return None
    return ChainFinding(
        channel,
        "voltage_folded",
        f"measurement chain: {channel} cannot be read as the voltage: {note}; the winding is not "
        "estimated from it, and no effect on it judged",
        FOLDED_ADVICE.format(ch=channel),
    )


def pwm_finding(channel: str, v: np.ndarray) -> ChainFinding | None:
    """``pwm_sampled_bare`` if ``v`` sits at a PWM converter's levels and changes level often."""
    share = pwm_level_changes(v)
    if share < PWM_CHANGES:
        return None
    return ChainFinding(
        channel,
        "pwm_sampled_bare",
        f"measurement chain: {channel} sits at its converter's levels and changes level in "
        f"{100 * share:.0f} % of the intervals: a PWM voltage sampled without an anti-aliasing "
        "filter, whose samples do not show how long it stayed at each level; the winding "
        "cannot be estimated from it, and no motor effect judged",
        PWM_ADVICE.format(ch=channel),
    )
