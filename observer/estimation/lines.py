"""Lines of a window's voltage that the samples show at the wrong frequency, and their removal.

A PWM chopper's pulses (4 kHz behind a 2 kHz carrier) are lines far above what the
anti-aliasing filter removes; sampled below twice their frequency they land at an alias
(4 kHz sampled at 5 kHz: 1 kHz), in the voltage and in the current alike. The model reads
a line where it lands: it predicts the current the winding would draw from a 1 kHz
voltage, four times what the same voltage at 4 kHz draws, and the fit moves the
inductance to close the gap (the P-12 behind a chopper at 5 kHz: La +16 % over the whole
recording, in every one of 20 seeds).

Such a line gives itself away by its admittance: the current's line over the voltage's is
what the winding admits at the line's true frequency, far below ``1/|Z|`` at the
frequency it is seen at (:func:`aliased_lines`). Removing the same band from the voltage
and from the current (:func:`notch`) is one linear filter applied to the input and the
output of a linear model: the relation between them is unchanged everywhere else, and
the line no longer speaks for a frequency it does not have (the notch's ringing at the
window's ends is left out with them, :func:`settle_samples`). A line the winding's
impedance explains (a bridge's ripple below Nyquist, the pulses' own line where the rate
resolves it) is kept: it carries the inductance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: A line is a run of bins above this many times the spectrum's median (its noise floor).
LINE_FLOOR = 8.0

#: ... and reaches down to where it falls below this many times the floor, plus
#: :data:`LINE_MARGIN_BINS` either side (the Hann window's main lobe).
LINE_FOOT = 3.0
LINE_MARGIN_BINS = 3

#: Lines looked at, strongest first.
MAX_LINES = 8

#: A line whose current admits less than this share of what the winding's impedance at the
#: line's frequency admits came from another frequency (the next image of a 1 kHz alias from
#: 4 kHz admits a quarter; a channel mismatch of the front ends moves it by less than half).
ALIASED_ADMITTANCE = 0.5

#: Below this frequency (Hz) the fluctuation is the drive's control and the load.
LINE_FLOOR_HZ = 20.0


def _spectrum(x: np.ndarray) -> np.ndarray:
    n = x.shape[0]
    return np.fft.rfft((x - x.mean()) * np.hanning(n))


def aliased_lines(
    v: np.ndarray, i: np.ndarray, dt: float, impedance_at: Callable[[float], complex]
) -> list[tuple[float, float]]:
    """The bands ``(low_hz, high_hz)`` of ``v``'s lines that the current ``i`` does not answer
    as the winding's impedance ``impedance_at(f_hz)`` would: aliases of a converter's
    content above the Nyquist frequency (module docstring). Empty for a voltage without
    lines or whose lines the impedance explains."""
    x = np.asarray(v, dtype=np.float64)
    y = np.asarray(i, dtype=np.float64)
    n = x.shape[0]
    if n < 64 or not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return []
    f = np.fft.rfftfreq(n, dt)
    sv, si = _spectrum(x), _spectrum(y)
    a = np.abs(sv)
    above = f >= LINE_FLOOR_HZ
    if not np.any(above):
        return []
    floor = float(np.median(a[above]))
    if not floor > 0.0:
        return []
    strong = above & (a > LINE_FLOOR * floor)
    foot = above & (a > LINE_FOOT * floor)
    bands: list[tuple[float, float]] = []
    taken = np.zeros(f.shape[0], dtype=bool)
    for peak in np.argsort(np.where(strong, a, 0.0))[::-1][:MAX_LINES]:
        if not strong[peak] or taken[peak]:
            continue
        lo = hi = int(peak)
        while lo > 0 and foot[lo - 1]:
            lo -= 1
        while hi < f.shape[0] - 1 and foot[hi + 1]:
            hi += 1
        lo = max(lo - LINE_MARGIN_BINS, 0)
        hi = min(hi + LINE_MARGIN_BINS, f.shape[0] - 1)
        taken[lo : hi + 1] = True
        band = slice(lo, hi + 1)
        # The current's line against the voltage's, least squares over the band.
        power = float(np.sum(np.abs(sv[band]) ** 2))
        admittance = abs(complex(np.sum(si[band] * np.conj(sv[band])))) / power
        expected = 1.0 / abs(impedance_at(float(f[peak])))
        if admittance < ALIASED_ADMITTANCE * expected:
            bands.append((float(f[lo]), float(f[hi])))
    return sorted(bands)


#: A notch is at least this wide (Hz): narrower ones ring for longer than a window spares.
NOTCH_MIN_WIDTH_HZ = 40.0

#: The notches' ringing has died down to this share after :func:`settle_samples`.
NOTCH_SETTLED = 1e-3


def _notch_filter(low_hz: float, high_hz: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """A 2nd-order IIR notch at the band's centre, as wide as the band (or the minimum)."""
    from scipy.signal import iirnotch

    centre = 0.5 * (low_hz + high_hz)
    width = max(high_hz - low_hz, NOTCH_MIN_WIDTH_HZ)
    b, a = iirnotch(centre, centre / width, fs=1.0 / dt)
    return np.asarray(b), np.asarray(a)


def notch(x: np.ndarray, dt: float, bands: list[tuple[float, float]]) -> np.ndarray:
    """``x`` with the ``bands`` (Hz) removed: one zero-phase IIR notch per band, run forward
    and backward (the same filter for the voltage and the current keeps their relation;
    the first and last :func:`settle_samples` ring and are to be left out)."""
    from scipy.signal import filtfilt

    out = np.asarray(x, dtype=np.float64).copy()
    for low, high in bands:
        b, a = _notch_filter(low, high, dt)
        if out.shape[0] > 3 * max(a.size, b.size):
            out = filtfilt(b, a, out)
    return out


def settle_samples(bands: list[tuple[float, float]], dt: float) -> int:
    """Samples at each end of a notched window in which the notches still ring: a notch of
    width ``B`` decays as ``exp(-pi B t)``."""
    if not bands:
        return 0
    width = min(max(high - low, NOTCH_MIN_WIDTH_HZ) for low, high in bands)
    return int(np.ceil(np.log(1.0 / NOTCH_SETTLED) / (np.pi * width) / dt))
