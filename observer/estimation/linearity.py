"""Whether a winding's voltage reading is linear in the voltage, seen at low frequency.

A PWM converter's pulses sampled in step with the ADC (a 2 kHz carrier's 4 kHz pulses at
fs = 2, 4 or 8 kHz; in general a harmonic ``N*f_p`` on a multiple of ``fs``) fold onto zero
frequency: every sample meets the anti-aliasing filter's residual ripple at the same phase of
the pulse, and what it adds depends on the duty cycle. The samples then read the voltage
through a static curve ``v + e(v)``. Nothing in a window shows it (no line, no jump: the
model sees a smooth voltage), its linear part is a gain error that moves ``R``, ``L`` and
``K`` together (the P-12 behind a chopper at 4 kHz: K -4 % at 62 std, Rf -4.5 % at 32 std),
and no model of the samples can take it out.

Its curved part can be seen where the voltage moves over a range: below ~20 Hz every front
end passes the winding's equation unchanged, ``v = R i + L di/dt + K if omega + c``, and a
static curve of the voltage leaves an equation error that a polynomial in ``v`` explains
(:func:`voltage_linearity`), once the motor's own curves (saturation, armature reaction, a
speed sensor's load error: :data:`MOTOR_TERMS`) have had their chance. Measured on the
simulator's choppers over 30 s (both motors, seeds 0-2, :data:`DEGREE` 8), as rms of the
largest voltage:

* sampled in step with the pulses (2, 4 and 8 kHz behind 4 kHz pulses): 0.34-1.5 % behind
  Butterworth filters at fs/4, the curve explaining 83-100 % of the error (0.08-0.09 % on one
  seed at 2 kHz whose voltage spans less, 83-87 %); 0.43-2.8 % behind RC voltage filters
  (24-92 %). Other carriers (1, 1.5, 2.5, 3 and 4 kHz, the P-12 at 2, 5 and 10 kHz): every
  rate that left a parameter beyond its tolerance or 3 std showed 0.062-1.5 % (74-100 %);
* a chopper at 5 or 10 kHz behind Butterworth filters: at most 0.08 %, explaining at most
  45 %; behind RC voltage filters 0.21-0.30 % at 5 kHz (not flagged; Ra 2.7-3.5 % off on the
  440 V motor) and 0.40-0.50 % at 10 kHz (flagged: Ra 3-6.5 % off at 5-9 std);
* a thyristor bridge behind filters: at most 0.02 %; the motor's effects of the diagnosis
  library on either drive (27 cases): at most 0.14 %, explaining at most 43 %.

A reading is taken for a curve at :data:`CURVE_SIZE` with :data:`CURVE_SHARE`, or at
:data:`CURVE_ALONE` (:attr:`Linearity.linear`); it is then not evidence about the motor, and
the estimate says so and holds. Good voltage transducers (closed-loop Hall, isolation
amplifiers) are linear to 0.1-0.2 % of their range. A transducer that curved would be held
too: the test cannot tell its curve from a folded converter's, and its gain error is of the
same size.

The curve shows only over a range of voltages: the first 8 s of a P-12 recording behind a
chopper at 8 kHz gave 0.12 % of the largest voltage (at 2 kHz 0.15 %), under the limits, where
12 s gave 0.94 % (0.32 %). A field's voltage follows
its current (``v ~ R i``), so a curve of it is one of the current too and says nothing: the
field is judged beside the armature instead (:func:`field_note`). Measured (the P-12's field
chopper, 30 s, 2/5/10 kHz, carriers 1-4 kHz): field choppers read well behind Butterworth
filters showed 0.12-0.31 % of the largest voltage, one folded in step at 5 kHz (Rf -4.5 % at 32
std) 0.23 %, and thyristor field bridges, whose fold the model puts back, 0.11-1.5 %; with the
curve allowed, the field's ``R`` and ``L`` moved by 50-100 % (the curve takes ``R i`` whole).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Below this frequency (Hz) the winding's equation is read: every anti-aliasing filter in use
#: (cutoffs at fs/4 and above) passes it to within 0.1 %, and the control's swings are in it.
LOW_HZ = 20.0

#: Block means are taken to about this rate (Hz) before the low-pass.
BLOCK_HZ = 200.0

#: Degree of the polynomial in the voltage (terms 2..DEGREE: the constant and the linear part
#: are the model's own offset and a gain that the parameters absorb).
DEGREE = 8

#: A curve that explains at least this share of the slow equation error (the motor's own
#: effects and every chain but an in-step chopper's: at most 0.45) ...
CURVE_SHARE = 0.7

#: ... and is at least this share of the largest voltage (rms), or one of at least
#: :data:`CURVE_ALONE` whatever else the error holds, is not the voltage's. The smallest
#: in-step fold measured that moved a parameter beyond its tolerance or its std: 0.062 %
#: (a 1.5 kHz carrier at 2 kHz, La -9 %); at 0.08-0.15 % (pulses at 3 and 4 times 2 kHz) Ra
#: read 1.3-2 % off at 24-26 std.
CURVE_SIZE = 0.0006
CURVE_ALONE = 0.003

#: Seconds of recording the test needs (the edges of the low-pass left out).
MIN_SECONDS = 5.0

#: Left out at each end after the zero-phase low-pass (s).
EDGE_S = 0.25

#: The daemon tests the last this many seconds ...
WATCH_SECONDS = 60.0

#: ... every this many seconds of new data.
RETEST_SECONDS = 10.0

#: Harmonics of the fold's period fitted (:class:`Fold`): the fold of a pulse harmonic ``N``
#: goes as ``sin(N pi d)`` in the duty ``d``, and a second harmonic takes up what the
#: filter's phase and a bipolar carrier add.
FOLD_HARMONICS = 2

#: The periods searched, as shares of the largest voltage: ``2 V_dc / N`` for a pulse
#: harmonic ``N`` from 1 (a chopper sampled in step: 1.9 times the largest voltage on the
#: P-12 at 2 kHz) to 15 (beyond it the filters leave nothing).
FOLD_PERIODS = (1.0 / 15.0, 4.0)

#: Candidate periods on the coarse grid (geometric), before the best is refined.
FOLD_GRID = 400

#: Blocks averaged together for the period search (200 Hz -> 50 Hz).
FOLD_DECIMATE = 4

#: Periods the voltages must span for a fold to explain a curve away (:attr:`Fold.pinned`):
#: a chopper's 5th harmonic folded at 10 kHz spans 4.6-4.9 of them on both motors, one sampled
#: in step 0.5-1.0 (the 440 V motor's at 8 kHz: 2.0).
FOLD_PINNED = 3.0

#: A fold explaining at least this share of the slow equation error that the motor's own terms
#: leave is taken out of the voltage (:attr:`Fold.usable`). Measured (30 s, both motors,
#: seeds 0-2): a chopper at 10 kHz behind Butterworth filters 0.95-0.98, at 5 kHz 0.59-0.64;
#: the same chopper's voltages averaged over each period (nothing folds) 0.015.
FOLD_SHARE = 0.5


@dataclass(frozen=True)
class Fold:
    """A converter's pulses folded onto zero frequency: a curve of the voltage periodic in it.

    A chopper's pulse train of duty ``d`` has harmonics ``N f_p`` of size ``~sin(N pi d)/N``;
    where one lands on a multiple of ``fs`` (4 kHz pulses at 10 kHz: ``5 f_p = 2 fs``) every
    sample meets what the anti-aliasing filter leaves of it at the same phase, and the reading
    is off by a periodic function of the duty, so of the mean voltage, with period
    ``2 V_dc / N``. Measured against the simulator's exact mean over each sample period
    (the 440 V motor behind a chopper at 10 kHz): a sine of 0.95 V and period 205 V, within
    0.1 V at every voltage; a polynomial of degree 8 explained 43 % of it, this model 98 %.
    Near a reversal its slope is a gain error of ~2 % that moves ``Ra`` and ``K`` alike.

    Attributes
    ----------
    period_v : float
        The period in the voltage (V).
    coefficients : tuple of float
        ``(a_1, b_1, a_2, b_2, ...)``: the fold is ``sum a_k cos(2 pi k v / P) + b_k sin(...)``
        (V).
    rms_v : float
        RMS of the slow equation error it explains (V).
    share : float
        Share of the slow equation error's power (after the motor's own terms) it explains.
    residual_v : float
        RMS of the slow equation error left after it (V): what the correction cannot vouch for.
    largest_v : float
        The largest |voltage| of the data it was fitted on (V): about the converter's supply,
        to which the pulses' harmonics, and so the fold, are proportional.
    span_v : float
        The range of the voltages it was fitted over (V, 0.5th to 99.5th percentile).
    """

    period_v: float
    coefficients: tuple[float, ...]
    rms_v: float
    share: float
    residual_v: float
    largest_v: float = math.nan
    span_v: float = math.nan

    @property
    def pinned(self) -> bool:
        """Whether the voltages span :data:`FOLD_PINNED` periods or more: the fold's linear
        part, a gain the parameters would take up, is then set by its periodic shape. A fold
        of a pulse train sampled in step (the fundamental on a multiple of fs: periods of
        1.9-4 times the largest voltage) is mostly such a gain, and is not taken for one that
        can be taken out."""
        return self.period_v * FOLD_PINNED <= self.span_v

    @property
    def seen(self) -> bool:
        """Whether the voltages span a whole period: a "period" longer than the voltages span
        is no periodic curve at all, only a smooth one, which anything that follows the
        operating point fits as well. A tachometer that lost 10 % of its reading 12 s into an
        ideal recording (the P-12, 2 kHz), tested over samples from both sides of the loss,
        left an error in the speed that a "fold" of period 1013 V over voltages spanning
        ~400 V explained to 58 %; taken out of the samples, it made the armature's windows
        read K 45 % and Ra 50 % low at stds of 0.1-0.4 %, and a false "K fell 45.5 %"."""
        return self.period_v <= self.span_v

    @property
    def usable(self) -> bool:
        """Whether the fold is taken out of the voltage (:data:`FOLD_SHARE`)."""
        return self.share >= FOLD_SHARE

    def __call__(self, voltage: np.ndarray) -> np.ndarray:
        """The fold at each *mean* voltage (V): a function of the duty, not of a sample."""
        v = np.asarray(voltage, dtype=np.float64)
        return np.asarray(_fold_columns(v, self.period_v) @ np.asarray(self.coefficients))

    @property
    def peak_v(self) -> float:
        """The fold's largest size over a period (V)."""
        v = np.linspace(0.0, self.period_v, 257)
        return float(np.max(np.abs(self(v))))

    def peak_for(self, voltage: np.ndarray) -> float:
        """The fold's peak scaled to another reading of the same converter, ``voltage`` (V):
        a pulse's harmonics are proportional to its height, so the fold to the voltage's
        range (its 99th percentile of |v| against :attr:`largest_v`)."""
        v = np.abs(np.asarray(voltage, dtype=np.float64))
        if not (self.largest_v > 0 and v.size):
            return 0.0
        return self.peak_v * float(np.percentile(v, 99.0)) / self.largest_v

    def of_samples(self, voltage: np.ndarray, dt: float) -> np.ndarray:
        """The fold to subtract from each of contiguous samples ``voltage`` (V; period ``dt``
        s), at their centred mean over a block (:data:`BLOCK_HZ`), as the fold was fitted: a
        sample itself carries what the filter leaves of the pulses (60 V rms on the 440 V
        motor at 10 kHz behind Butterworths at fs/4), on which a curve of period 200 V is
        meaningless. Against the simulator's exact means (12 s, 5 seeds of both motors) the
        slow error fell from 0.11-0.57 V to 0.04-0.08 V so; taken at the samples, by at most a
        quarter."""
        from scipy.ndimage import uniform_filter1d

        v = np.asarray(voltage, dtype=np.float64)
        block = max(1, int(round(1.0 / (BLOCK_HZ * dt))))
        return self(uniform_filter1d(v, block, mode="nearest") if block > 1 else v)

    def to_dict(self) -> dict[str, float | bool]:
        return {
            "period_v": self.period_v,
            "rms_v": self.rms_v,
            "share": self.share,
            "residual_v": self.residual_v,
        }


def _fold_columns(v: np.ndarray, period: float) -> np.ndarray:
    """``cos, sin`` of ``2 pi k v / period`` for ``k = 1..FOLD_HARMONICS``, as columns."""
    phase = 2.0 * np.pi * v[:, None] * np.arange(1, FOLD_HARMONICS + 1) / period
    out = np.empty((v.shape[0], 2 * FOLD_HARMONICS))
    out[:, 0::2] = np.cos(phase)
    out[:, 1::2] = np.sin(phase)
    return out


@dataclass(frozen=True)
class Linearity:
    """How far a voltage reading is from linear, over the low-frequency winding equation.

    Attributes
    ----------
    curve_v : float
        RMS of the slow equation error that a static curve of the voltage explains (V).
    share : float
        Share of the slow equation error's power it explains (0-1).
    largest_v : float
        The largest |voltage| of the recording (V, 99.5th percentile of the block means).
    seconds : float
        Length of the data tested (s).
    fold : Fold or None
        The converter's folded pulses, periodic in the voltage (armature only; None where
        not fitted).
    """

    curve_v: float
    share: float
    largest_v: float
    seconds: float
    fold: Fold | None = None
    after_fold: tuple[float, float] | None = None

    @property
    def correction(self) -> Fold | None:
        """The fold to take out of the voltage before the armature is estimated: a usable one
        (:attr:`Fold.usable`) of a reading that is linear otherwise (a reading held for its
        curve is not described either way), whose period the voltages span at least once
        (:attr:`Fold.seen`)."""
        fold = self.fold
        return fold if fold is not None and fold.usable and fold.seen and self.linear else None

    @property
    def linear_as_read(self) -> bool:
        """Whether the reading, fold and all, shows no curve (:data:`CURVE_SHARE`,
        :data:`CURVE_SIZE`, :data:`CURVE_ALONE`)."""
        return _no_curve(self.curve_v, self.share, self.largest_v)

    @property
    def size(self) -> float:
        """The curve as a share of the largest voltage (0 where there is none)."""
        return self.curve_v / self.largest_v if self.largest_v > 0 else 0.0

    @property
    def linear(self) -> bool:
        """False when the reading carries a static curve that is not the sensor's and that no
        usable, pinned fold (:attr:`Fold.pinned`) explains: behind RC voltage filters a
        chopper's fold at 10 kHz read as a curve of 0.37-0.49 % of the largest voltage (held),
        0.02-0.05 % once the fold was fitted beside it."""
        if self.linear_as_read:
            return True
        fold = self.fold
        if fold is None or not (fold.usable and fold.pinned) or self.after_fold is None:
            return False
        return _no_curve(*self.after_fold, self.largest_v)

    def to_dict(self) -> dict[str, float | bool | dict[str, float | bool]]:
        out: dict[str, float | bool | dict[str, float | bool]] = {
            "curve_v": self.curve_v,
            "share": self.share,
            "largest_v": self.largest_v,
            "seconds": self.seconds,
            "linear": self.linear,
            "linear_as_read": self.linear_as_read,
        }
        if self.fold is not None:
            out["fold"] = {**self.fold.to_dict(), "taken_out": self.correction is not None}
        return out


def _no_curve(curve_v: float, share: float, largest_v: float) -> bool:
    """Whether a curve of ``curve_v`` (V rms) explaining ``share`` of the slow error is below
    the limits (:data:`CURVE_SHARE` with :data:`CURVE_SIZE`, or :data:`CURVE_ALONE`)."""
    size = curve_v / largest_v if largest_v > 0 else 0.0
    return not ((share >= CURVE_SHARE and size >= CURVE_SIZE) or size >= CURVE_ALONE)


def applies_to(intersample: str) -> bool:
    """Whether the test reads a voltage under the ``intersample`` model: not ``switched``,
    whose model puts the converter's waveform between the samples itself (an unfiltered
    bridge's samples are instantaneous values of its sine segments, apart from the period's
    mean by what the firing angle, and so the voltage, decides: a curve of the voltage, 0.17-0.23 %
    of the largest at 2 kHz, that the model already describes)."""
    return intersample != "switched"


def nonlinear_note(result: Linearity | None, circuit: str) -> str:
    """Why a reading whose test is ``result`` cannot describe the ``circuit`` ("" when it can)."""
    if result is None or result.linear:
        return ""
    return (
        f"the {circuit} voltage's samples follow a curve of the voltage, not the voltage: "
        f"{result.curve_v:.2g} V rms ({100 * result.size:.2g} % of the "
        f"largest) explains {100 * result.share:.0f} % of the slow error of the winding's "
        "equation. A converter's pulses sampled in step with the ADC fold onto zero "
        "frequency and read as a gain and curve that no model of the samples can take out: "
        "sample at a rate that is not a multiple of half the pulse frequency, or average the "
        "voltage over each period"
    )


def field_note(armature: Linearity | None, field_voltage: np.ndarray, dt: float) -> str:
    """Why the field cannot be described beside an armature whose reading is ``armature``
    ("" when it can).

    The field's voltage follows its current, so a curve cannot be seen in it. But where the
    armature's pulses fold and the field's voltage shows no mains ripple, the field is fed by a
    chopper too, on the drive's PWM clock as a rule, and its pulses fold alike: its steady
    voltage reads a gain it cannot show (the simulator's field chopper at 4 and 8 kHz: Rf
    1.6-8.6 % off at 2.5-47 std). A field bridge puts nearly all of its ripple at mains
    harmonics (:func:`made_by_a_bridge`) and is left as it is.
    """
    if armature is None or armature.linear or made_by_a_bridge(field_voltage, dt, winding="field"):
        return ""
    return (
        "the armature's voltage samples follow a curve of the voltage (a converter's pulses "
        "sampled in step with the ADC), and the field's voltage shows no mains ripple: a "
        "chopper's, whose pulses fold alike on the drive's PWM clock and read as a gain its "
        "steady voltage cannot show; sample at a rate that is not a multiple of half the "
        "pulse frequency, or average the voltages over each period"
    )


#: The motor's own curves, as block means beside the voltage's powers (armature only): the
#: flux as a cubic in the field current (saturation) and, times it, in the armature current
#: (armature reaction; a speed sensor's load-dependent error), each times the speed, the
#: speed times the armature current, and the sign of the armature current (a brush drop).
#: Taken out first, they leave a curve of the voltage only what depends on the voltage itself
#: (armature reaction 5 %: 0.81 % of the largest voltage without them, 0.04 % with them; a
#: brush drop of 1 V behind a chopper at 10 kHz kept the pulses' fold below
#: :data:`FOLD_SHARE` of what was left, and the diagnosis read the fold as unexplained).
MOTOR_TERMS = 8


#: Below this frequency (Hz) a bridge's ripple is looked for: its pulse rate and first
#: harmonics (100-360 Hz on 50/60 Hz mains), not a chopper's alias that happens to land on a
#: mains harmonic (4 kHz pulses at 5 kHz: 1 kHz, 20 x 50 Hz).
BRIDGE_RIPPLE_HZ = 400.0


def made_by_a_bridge(voltage: np.ndarray, dt: float, *, winding: str) -> bool:
    """Whether ``voltage`` shows a line-commutated bridge's ripple below
    :data:`BRIDGE_RIPPLE_HZ` (:func:`~observer.estimation.intersample.mains_ripple_share` at
    least :data:`~observer.estimation.stages.CONVERTER_RIPPLE`). Measured (the P-12, 1 s
    windows, 2/5/10 kHz, Butterworth or RC voltage filters): bridges 0.99-1.00, choppers
    0.00-0.05; unfiltered, a chopper's alias on 1 kHz read 0.83-0.99. ``winding``, required
    (``field`` or ``armature``): for the armature only a 6-pulse bridge's lines count
    (300/360 Hz), for the field every mains harmonic: a chopper's armature beside a field bridge
    read 0.33-0.78 on every mains harmonic (the EMF carries the field current's 100 Hz
    ripple), so the armature's linearity test was never run, and the traction motor behind a
    chopper sampled in step with its carrier published Ra -32 % and K -29 % as ``ok`` in its
    first windows, held from then on."""
    from scipy.signal import butter, sosfiltfilt

    from observer.estimation.intersample import mains_ripple_share
    from observer.estimation.stages import CONVERTER_RIPPLE

    if winding not in ("field", "armature"):
        raise ValueError(f"winding must be 'field' or 'armature', not {winding!r}")
    v = np.asarray(voltage, dtype=np.float64)
    if v.shape[0] < 64 or not np.all(np.isfinite(v)):
        return False
    nyquist = 0.5 / dt
    if BRIDGE_RIPPLE_HZ < 0.9 * nyquist:
        v = sosfiltfilt(butter(4, BRIDGE_RIPPLE_HZ / nyquist, output="sos"), v)
    return (
        mains_ripple_share(v, dt, harmonic_step=6 if winding == "armature" else 1)
        >= CONVERTER_RIPPLE
    )


class LinearityAccumulator:
    """Block means of what :func:`voltage_linearity` needs, added chunk by chunk.

    The voltage's powers (and the motor's own curves, :data:`MOTOR_TERMS`) are averaged before
    the low-pass (a curve acts on the instantaneous values); the voltage is scaled by the
    first chunk's largest |voltage| so that its powers stay near 1.

    Parameters
    ----------
    dt : float
        Sample period (s).
    keep_seconds : float, optional
        Keep only the newest this many seconds (None: everything).
    """

    def __init__(self, dt: float, keep_seconds: float | None = None) -> None:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        self.dt = float(dt)
        self.block = max(1, int(round(1.0 / (BLOCK_HZ * dt))))
        self.keep_blocks = (
            None if keep_seconds is None else max(1, int(keep_seconds / (self.block * self.dt)))
        )
        self.scale: float | None = None
        self.added_seconds = 0.0  # everything ever added (s), kept or not
        self._rows: list[np.ndarray] = []
        self._carry: np.ndarray | None = None

    @property
    def seconds(self) -> float:
        """Seconds held (in whole blocks)."""
        return sum(r.shape[0] for r in self._rows) * self.block * self.dt

    def reset(self) -> None:
        """Forget everything (a gap: the low-pass needs continuous data)."""
        self._rows.clear()
        self._carry = None

    def add(
        self,
        voltage: np.ndarray,
        current: np.ndarray,
        field_current: np.ndarray | None = None,
        speed: np.ndarray | None = None,
    ) -> None:
        """Append contiguous samples (the armature's with its ``field_current`` and ``speed``;
        the field's without)."""
        v = np.asarray(voltage, dtype=np.float64)
        i = np.asarray(current, dtype=np.float64)
        i_f = np.zeros_like(v) if field_current is None else np.asarray(field_current, float)
        w = np.zeros_like(v) if speed is None else np.asarray(speed, dtype=np.float64)
        if not (v.shape == i.shape == i_f.shape == w.shape) or v.ndim != 1:
            raise ValueError("voltage, currents and speed must be 1-d arrays of one length")
        if self.scale is None:
            top = float(np.max(np.abs(v))) if v.size else 0.0
            if not (math.isfinite(top) and top > 0):
                return
            self.scale = 1.5 * top
        u = v / self.scale
        emf = i_f * w
        cols = np.empty((v.shape[0], DEGREE + 3 + MOTOR_TERMS))
        cols[:, : DEGREE + 1] = u[:, None] ** np.arange(DEGREE + 1)
        cols[:, DEGREE + 1] = i
        cols[:, DEGREE + 2] = emf
        motor = cols[:, DEGREE + 3 :]
        motor[:, 0] = w
        motor[:, 1] = emf * i_f
        motor[:, 2] = emf * i_f * i_f
        motor[:, 3] = emf * i
        motor[:, 4] = emf * i * i
        motor[:, 5] = emf * i * i * i
        motor[:, 6] = w * i
        motor[:, 7] = np.sign(i)
        if self._carry is not None:
            cols = np.concatenate([self._carry, cols])
        n = (cols.shape[0] // self.block) * self.block
        if n:
            self._rows.append(cols[:n].reshape(-1, self.block, cols.shape[1]).mean(axis=1))
        self._carry = cols[n:] if n < cols.shape[0] else None
        self.added_seconds += v.shape[0] * self.dt
        held = sum(r.shape[0] for r in self._rows)
        if self.keep_blocks is not None and held > 1.25 * self.keep_blocks:
            self._rows = [np.concatenate(self._rows)[-self.keep_blocks :]]

    def result(self, *, armature: bool) -> Linearity | None:
        """The test over what was added (``armature``: with its EMF and the motor's own curves);
        None with too little, or non-finite, data."""
        return self.snapshot(armature=armature)()

    def snapshot(self, *, armature: bool) -> Callable[[], Linearity | None]:
        """:meth:`result` over what was added so far, to be computed later (in another
        thread: the data are copied now; adding more does not change it)."""
        if self.scale is None or not self._rows:
            return lambda: None
        rows = np.concatenate(self._rows)
        if self.keep_blocks is not None:
            rows = rows[-self.keep_blocks :]
        if not np.all(np.isfinite(rows)):
            return lambda: None
        return functools.partial(_test, rows, self.scale, self.block * self.dt, armature=armature)


def voltage_linearity(
    voltage: np.ndarray,
    current: np.ndarray,
    dt: float,
    field_current: np.ndarray | None = None,
    speed: np.ndarray | None = None,
) -> Linearity | None:
    """Test a winding's voltage reading for a static curve (module docstring).

    Parameters
    ----------
    voltage, current : (n,) arrays
        The winding's voltage (V) and current (A), contiguous samples.
    dt : float
        Sample period (s).
    field_current, speed : (n,) arrays, optional
        The armature's ``if`` (A) and ``omega`` (rad/s); None for the field.

    Returns
    -------
    Linearity or None
        None when the recording is shorter than :data:`MIN_SECONDS` or not finite.
    """
    acc = LinearityAccumulator(dt)
    acc.add(voltage, current, field_current, speed)
    return acc.result(armature=field_current is not None and speed is not None)


def _test(rows: np.ndarray, scale: float, dt_block: float, *, armature: bool) -> Linearity | None:
    from scipy.signal import butter, filtfilt

    n = rows.shape[0]
    edge = int(math.ceil(EDGE_S / dt_block))
    seconds = (n - 2 * edge) * dt_block
    if seconds < MIN_SECONDS:
        return None
    powers = rows[:, : DEGREE + 1]
    v = powers[:, 1] * scale
    lo, hi = np.percentile(powers[:, 1], [0.5, 99.5])
    largest = float(np.percentile(np.abs(v), 99.5))
    if not (hi > lo and largest > 0):
        return None
    # T_j((u - c)/h) as a polynomial in u, applied to the block means of u^k.
    curve = []
    for j in range(2, DEGREE + 1):
        coef = (
            np.polynomial.Chebyshev.basis(j, domain=[lo, hi])
            .convert(kind=np.polynomial.Polynomial)
            .coef
        )
        curve.append(powers[:, : coef.shape[0]] @ coef)
    current = rows[:, DEGREE + 1]
    others = [rows[:, DEGREE + 2], *rows[:, DEGREE + 3 :].T] if armature else []
    nyquist = 0.5 / dt_block
    signals = [v, current, *others, *curve]
    smooth: Callable[[np.ndarray], np.ndarray] = lambda x: x  # noqa: E731
    # (Blocks too slow to low-pass: a recording in other time units. A fold, a sampling effect
    # far above the winding's equation, is not looked for there.)
    low_passed = LOW_HZ < 0.9 * nyquist
    if low_passed:
        b, a = butter(2, LOW_HZ / nyquist)
        smooth = functools.partial(filtfilt, b, a, axis=0)
        signals = [smooth(x) for x in signals]
    keep = slice(edge, n - edge)
    y = signals[0][keep]
    base = [signals[1][keep], np.gradient(signals[1], dt_block)[keep], np.ones_like(y)]
    base += [x[keep] for x in signals[2 : 2 + len(others)]]
    curves = [x[keep] for x in signals[2 + len(others) :]]
    a0, r0 = _fitted(base, y)
    p0, p1 = float(np.mean(r0**2)), float(np.mean(_fitted(base + curves, y)[1] ** 2))
    if not p0 > 0:
        return Linearity(0.0, 0.0, largest, seconds)
    fold = _fit_fold(v, r0, a0, keep, dt_block, largest) if armature and low_passed else None
    after = None
    if fold is not None:
        # The curve test again with the fold beside the motor's terms.
        folded = list(smooth(_fold_columns(v, fold.period_v))[keep].T)
        fold = dataclasses.replace(fold, span_v=float(hi - lo) * scale)
        q0 = float(np.mean(_fitted(base + folded, y)[1] ** 2))
        q1 = float(np.mean(_fitted(base + folded + curves, y)[1] ** 2))
        if q0 > 0:
            after = _curve(q0, q1)
    return Linearity(
        *_curve(p0, p1), largest_v=largest, seconds=seconds, fold=fold, after_fold=after
    )


def _fitted(columns: list[np.ndarray], y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ``columns`` scaled (:func:`_scaled`) as one matrix, and what of ``y`` their least
    squares leaves."""
    a = _scaled(np.column_stack(columns))
    return a, y - a @ np.linalg.lstsq(a, y, rcond=None)[0]


def _curve(p0: float, p1: float) -> tuple[float, float]:
    """RMS (V) and share of a slow error of power ``p0`` that a curve explains, leaving ``p1``."""
    return math.sqrt(max(p0 - p1, 0.0)), max(0.0, 1.0 - p1 / p0)


def _fit_fold(
    v: np.ndarray, r0: np.ndarray, a0: np.ndarray, keep: slice, dt_block: float, largest: float
) -> Fold | None:
    """The :class:`Fold` that explains most of ``r0``, the slow equation error left by the
    motor's terms (the columns ``a0``), over the block means ``v`` (V; ``keep``: the blocks
    ``r0`` and ``a0`` hold, ``dt_block`` apart): its period searched over
    :data:`FOLD_PERIODS` on a geometric grid, then refined between the best one's neighbours.
    The fold acts on the samples; taken at the blocks' mean voltage it is within a few percent
    of that at a 200 Hz block (the voltage moves far less than a period within 5 ms). The
    search runs on means of :data:`FOLD_DECIMATE` blocks (everything is below
    :data:`LOW_HZ` by then): the candidates' low-pass is most of its cost."""
    from scipy.signal import butter, filtfilt

    step = FOLD_DECIMATE
    start = keep.start or 0
    count = (r0.shape[0] // step) * step

    def decimated(x: np.ndarray) -> np.ndarray:
        return np.asarray(x[:count].reshape(count // step, step, *x.shape[1:]).mean(axis=1))

    nyquist = 0.5 / (dt_block * step)
    b, a = butter(2, min(LOW_HZ / nyquist, 0.9))
    r = decimated(r0)
    q = np.linalg.qr(decimated(a0))[0]
    r -= q @ (q.T @ r)
    p0 = float(np.mean(r**2))
    if not p0 > 0:
        return None

    def explained(periods: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        gains, coefs = np.empty(periods.shape[0]), []
        for j, period in enumerate(periods):
            # Block means of the columns over the kept stretch, then the low-pass.
            cols = _fold_columns(v[start : start + count], float(period))
            cols = filtfilt(b, a, decimated(cols), axis=0)
            cols -= q @ (q.T @ cols)
            coef = np.linalg.lstsq(cols, r, rcond=None)[0]
            gains[j] = p0 - float(np.mean((r - cols @ coef) ** 2))
            coefs.append(coef)
        return gains, coefs

    grid = np.geomspace(FOLD_PERIODS[0] * largest, FOLD_PERIODS[1] * largest, FOLD_GRID)
    gains, _ = explained(grid)
    i = int(np.argmax(gains))
    fine = np.geomspace(grid[max(i - 1, 0)], grid[min(i + 1, grid.shape[0] - 1)], 41)
    gains, coefs = explained(fine)
    j = int(np.argmax(gains))
    gain = max(float(gains[j]), 0.0)
    if not math.isfinite(gain):
        return None
    return Fold(
        period_v=float(fine[j]),
        coefficients=tuple(float(c) for c in coefs[j]),
        rms_v=math.sqrt(gain),
        share=min(gain / p0, 1.0),
        residual_v=math.sqrt(max(p0 - gain, 0.0)),
        largest_v=largest,
    )


def _scaled(a: np.ndarray) -> np.ndarray:
    """``a`` with unit-rms columns (the motor's curves span many decades in SI units)."""
    norm = np.sqrt(np.mean(a**2, axis=0))
    return a / np.where(norm > 0, norm, 1.0)
