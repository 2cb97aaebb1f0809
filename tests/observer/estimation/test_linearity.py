"""A voltage reading that follows a curve of the voltage: a converter's pulses folded onto
zero frequency, seen in the armature's slow equation error and held."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from observer.estimation.linearity import (
    MIN_SECONDS,
    Fold,
    Linearity,
    LinearityAccumulator,
    nonlinear_note,
    voltage_linearity,
)


@functools.cache
def _recording(drive: str, fs: float, effect: str | None = None, seed: int = 1):
    """12 s of the P-12 behind ``drive`` and 2nd-order filters at fs/4 (not configured)."""
    from bench.accuracy_rates import drive_spec
    from observer.estimation.motor import P12
    from observer.simulation.effects_sim import DEFAULT_MAGNITUDES
    from observer.simulation.simulate import simulate

    effects = {effect: DEFAULT_MAGNITUDES[effect]} if effect else None
    return simulate(
        P12, duration_s=12.0, sample_rate_hz=fs, seed=seed, drive=drive_spec(drive),
        effects=effects,
    )  # fmt: skip


def _linearity(rec):
    s = rec.signals
    return voltage_linearity(s["va"], s["ia"], rec.dt, s["if"], s["omega"])


@pytest.mark.parametrize("fs", [2000.0, 4000.0, 8000.0])
@pytest.mark.slow
def test_a_chopper_sampled_in_step_with_its_pulses_reads_a_curve(fs):
    """The chopper's pulses at 4 kHz: a harmonic on a multiple of fs at 2, 4 and 8 kHz."""
    result = _linearity(_recording("chopper", fs))
    assert result is not None and not result.linear
    assert result.share > 0.9
    assert "curve of the voltage" in nonlinear_note(result, "armature")


@pytest.mark.parametrize(
    ("drive", "fs", "effect"),
    [
        ("chopper", 5000.0, None),  # its pulses alias to 1 kHz: a line, not a curve
        ("thyristor", 2000.0, None),
        # the motor's own curves: flux against field and armature current
        ("thyristor", 2000.0, "armature_reaction"),
        ("chopper", 5000.0, "field_saturation"),
    ],
)
@pytest.mark.slow
def test_a_linear_reading_is_not_taken_for_a_curve(drive, fs, effect):
    result = _linearity(_recording(drive, fs, effect))
    assert result is not None and result.linear
    assert nonlinear_note(result, "armature") == ""


def test_chunks_give_what_the_whole_gives_and_short_data_gives_nothing():
    rec = _recording("chopper", 4000.0)
    s = rec.signals
    whole = _linearity(rec)
    acc = LinearityAccumulator(rec.dt)
    for start in range(0, s["va"].shape[0], 777):  # chunks that do not divide the blocks
        part = slice(start, start + 777)
        acc.add(s["va"][part], s["ia"][part], s["if"][part], s["omega"][part])
    chunked = acc.result(armature=True)
    assert chunked is not None and whole is not None
    assert chunked.share == pytest.approx(whole.share, rel=1e-9)
    assert chunked.curve_v == pytest.approx(whole.curve_v, rel=1e-9)
    n = int(MIN_SECONDS / rec.dt)
    assert voltage_linearity(s["va"][:n], s["ia"][:n], rec.dt, s["if"][:n], s["omega"][:n]) is None
    acc.reset()
    assert acc.result(armature=True) is None
    assert voltage_linearity(np.zeros(n * 2), np.zeros(n * 2), rec.dt) is None


@pytest.mark.slow
def test_the_whole_recording_estimate_holds_a_reading_that_follows_a_curve():
    """At 4 kHz the fold's gain moved K by more than 1 %, at a std that called it exact:
    the estimate now says its model does not describe the armature, nor the field chopper
    beside it (its pulses fold alike; a steady field cannot show it). At 5 kHz both describe."""
    from observer.config import EstimateConfig
    from observer.estimation import estimate_recording
    from observer.estimation.motor import P12

    settings = EstimateConfig(particles=30, iterations=30)
    folded = estimate_recording(_recording("chopper", 4000.0), settings=settings)
    armature = folded["armature"]
    assert not armature.describes_window
    assert "curve of the voltage" in armature.note
    assert abs(armature.emf_constant_h / P12.emf_constant_h - 1) > 0.01
    assert armature.to_dict()["voltage_linearity"]["linear"] is False
    assert not folded["field"].describes_window
    assert "no mains ripple" in folded["field"].note
    clean = estimate_recording(_recording("chopper", 5000.0), settings=settings)
    assert clean["armature"].describes_window and clean["field"].describes_window
    assert clean["armature"].to_dict()["voltage_linearity"]["linear"] is True


def test_a_field_bridge_beside_a_folded_armature_is_estimated_as_before():
    """A field bridge's ripple sits at mains harmonics: not a chopper on the PWM clock. A
    chopper's alias that lands on one (4 kHz pulses at 5 kHz: 1 kHz = 20 x 50 Hz) is not
    taken for a bridge's ripple."""
    from observer.estimation.linearity import field_note, made_by_a_bridge

    bridge = _bridge_field_recording()
    aliased = _recording("chopper", 5000.0)
    n = int(1 / aliased.dt)
    assert made_by_a_bridge(bridge.signals["vf"][:4000], bridge.dt, winding="field")
    assert not made_by_a_bridge(aliased.signals["vf"][:n], aliased.dt, winding="field")
    assert not made_by_a_bridge(aliased.signals["va"][:n], aliased.dt, winding="armature")

    folded = _linearity(_recording("chopper", 4000.0))
    assert not folded.linear
    chopper = _recording("chopper", 4000.0)
    assert "no mains ripple" in field_note(folded, chopper.signals["vf"], chopper.dt)
    bridge = _bridge_field_recording()
    assert field_note(folded, bridge.signals["vf"], bridge.dt) == ""
    linear = _linearity(_recording("chopper", 5000.0))
    assert field_note(linear, chopper.signals["vf"], chopper.dt) == ""


@functools.cache
def _bridge_field_recording():
    from bench.accuracy_rates import drive_spec
    from observer.estimation.motor import P12
    from observer.simulation.converter import ConverterSpec
    from observer.simulation.simulate import simulate

    drive = drive_spec("chopper").replace(
        converter=ConverterSpec(armature="chopper", field="bridge-1p")
    )
    return simulate(P12, duration_s=4.0, sample_rate_hz=4000.0, seed=1, drive=drive)


@functools.cache
def _chopper_at_10_khz(drive: str = "chopper"):
    """12 s of the 440 V motor behind a 2 kHz chopper (4 kHz pulses), sampled at 10 kHz behind
    2nd-order filters at fs/4 (not configured), with the simulator's truth."""
    from bench.window_honesty import _drive
    from observer.estimation.motor import MOTORS
    from observer.simulation.converter_drive import simulate_converter

    return simulate_converter(
        MOTORS["industrial-440v"], _drive(drive, 10000.0), duration_s=12.0,
        sample_rate_hz=10000.0, noise=0.002, seed=0, want_truth=True,
    )  # fmt: skip


@pytest.mark.slow
def test_pulses_folded_at_10_khz_are_a_curve_periodic_in_the_voltage_and_taken_out():
    """The pulses' 5th harmonic (20 kHz = 2 fs) meets every sample at one phase: the reading
    is off by a periodic function of the duty, so of the voltage. Too small to hold the
    armature for (the reading is linear to the test), it is fitted and taken out; against
    the simulator's exact mean over each sample period the slow error shrinks. Where the
    voltages are averaged over each period nothing folds, and nothing is taken out."""
    from scipy.signal import butter, filtfilt

    rec, truth = _chopper_at_10_khz()
    s = {c: np.asarray(rec[c], dtype=float) for c in ("va", "ia", "if", "omega")}
    result = voltage_linearity(s["va"], s["ia"], rec.dt, s["if"], s["omega"])
    assert result is not None and result.linear
    fold = result.correction
    assert fold is not None and fold.share > 0.8
    assert result.to_dict()["fold"]["taken_out"] is True
    # (the first and last 0.5 s left out: the low-pass rings there)
    b, a = butter(2, 20.0 * 2 * rec.dt)
    inner = slice(5000, -5000)
    error = filtfilt(b, a, s["va"] - np.asarray(truth.va_mean))[inner]
    taken_out = s["va"] - fold.of_samples(s["va"], rec.dt)
    left = filtfilt(b, a, taken_out - np.asarray(truth.va_mean))[inner]
    assert np.std(left) < 0.4 * np.std(error)  # 0.24 -> 0.07 V
    # A sample carries what the filter leaves of the pulses: the fold taken at the samples
    # themselves instead of their mean leaves the error as it was.
    at_samples = filtfilt(b, a, s["va"] - fold(s["va"]) - np.asarray(truth.va_mean))[inner]
    assert np.std(at_samples) > 0.8 * np.std(error)

    averaged, _ = _chopper_at_10_khz("chopper-averaged-voltages")
    a_s = {c: np.asarray(averaged[c], dtype=float) for c in ("va", "ia", "if", "omega")}
    plain = voltage_linearity(a_s["va"], a_s["ia"], averaged.dt, a_s["if"], a_s["omega"])
    assert plain is not None and plain.fold is not None and plain.fold.share < 0.1
    assert plain.correction is None


def test_a_reversal_window_is_right_once_the_fold_is_taken_out():
    """At a reversal (mean voltage near zero) the fold's slope is a gain error of ~2 % that
    moved Ra and K alike: K 1 % off at 10 std in the window of 5.5-6.5 s. Taken out, the
    window's K and Ra are within their stds."""
    from observer.estimation import estimate_armature
    from observer.estimation.motor import MOTORS

    rec, _ = _chopper_at_10_khz()
    s = {c: np.asarray(rec[c], dtype=float) for c in ("va", "ia", "if", "omega")}
    fold = voltage_linearity(s["va"], s["ia"], rec.dt, s["if"], s["omega"]).correction
    motor = MOTORS["industrial-440v"]
    w = slice(55_000, 65_000)
    ok = {}
    for name, va in (
        ("raw", s["va"][w]),
        ("taken out", s["va"][w] - fold.of_samples(s["va"][w], rec.dt)),
    ):
        est = estimate_armature(
            va, s["ia"][w], s["if"][w], s["omega"][w], rec.dt, intersample="smooth",
            n_particles=40, max_iterations=40, rng=0,
        )  # fmt: skip
        ok[name] = [
            abs(est.emf_constant_h - motor.emf_constant_h) / est.std["K"],
            abs(est.resistance_ohm - motor.armature_resistance_ohm) / est.std["R"],
        ]
    assert ok["raw"][0] > 4.0
    assert max(ok["taken out"]) < 2.0


def test_a_field_chopper_beside_a_folded_armature_carries_the_fold_as_an_offset():
    """The field's steady voltage cannot show a fold: it is an offset that Rf takes up whole.
    Beside an armature whose fold was fitted, the field's Rf std carries the fold's peak,
    scaled to the field's voltage, shared by the windows at that level; a field bridge's is
    left as it is, and so is every field without a fold."""
    from observer.estimation import estimate_field
    from observer.estimation.estimate import with_field_fold

    rec, _ = _chopper_at_10_khz()
    s = {c: np.asarray(rec[c], dtype=float) for c in ("va", "ia", "vf", "if", "omega")}
    fold = voltage_linearity(s["va"], s["ia"], rec.dt, s["if"], s["omega"]).correction
    w = slice(0, 10_000)
    est = estimate_field(s["vf"][w], s["if"][w], rec.dt, n_particles=30, max_iterations=30, rng=0)
    wide = with_field_fold(est, fold, s["vf"][w], rec.dt)
    peak = fold.peak_v * np.percentile(np.abs(s["vf"][w]), 99.0) / fold.largest_v
    move = est.resistance_ohm * peak / np.mean(np.abs(s["vf"][w]))
    assert wide.std["R"] == pytest.approx(np.hypot(est.std["R"], move), rel=1e-9)
    assert wide.shared_std["R"] >= move
    assert wide.std["L"] == est.std["L"]
    assert with_field_fold(est, None, s["vf"][w], rec.dt) is est
    bridge = _bridge_field_recording()
    vf = np.asarray(bridge.signals["vf"][:4000], dtype=float)
    assert with_field_fold(est, fold, vf, bridge.dt) is est


def test_a_curve_that_a_pinned_fold_explains_is_taken_out_not_held():
    """Behind RC voltage filters a chopper's fold at 10 kHz is large enough to read as a curve
    (0.37-0.49 % of the largest voltage): held, though the fold, fitted beside the motor's
    terms, leaves no curve (0.02-0.05 %). A fold whose period the voltages span three times
    or more is set by its periodic shape and is taken out instead; one of a chopper sampled in
    step (a period of about the voltages' span: mostly a gain) leaves the reading held."""
    from observer.estimation.linearity import CURVE_ALONE, Fold, Linearity

    largest = 240.0
    pinned = Fold(105.0, (0.0, 2.0, 0.0, 0.1), 1.7, 0.95, 0.05, largest_v=largest, span_v=460.0)
    in_step = dataclasses.replace(pinned, period_v=449.0)
    curved = dict(curve_v=2 * CURVE_ALONE * largest, share=0.3, largest_v=largest, seconds=30.0)
    after = (0.0002 * largest, 0.1)
    result = Linearity(**curved, fold=pinned, after_fold=after)
    assert not result.linear_as_read and result.linear and result.correction is pinned
    assert result.to_dict()["linear_as_read"] is False
    held = Linearity(**curved, fold=in_step, after_fold=after)
    assert not held.linear and held.correction is None
    # (usable, but not taken out of a reading that is held: the output must not say it was)
    assert in_step.usable and held.to_dict()["fold"]["taken_out"] is False
    still_curved = Linearity(**curved, fold=pinned, after_fold=(2 * CURVE_ALONE * largest, 0.9))
    assert not still_curved.linear
    weak = Linearity(**curved, fold=dataclasses.replace(pinned, share=0.3), after_fold=after)
    assert not weak.linear


@pytest.mark.parametrize(("period_v", "taken_out"), [(1013.0, False), (400.0, True), (106.0, True)])
def test_a_fold_longer_than_the_voltages_span_is_not_taken_out(period_v, taken_out):
    """A "period" the voltages do not span once is no periodic curve, only a smooth one that
    anything following the operating point fits as well: a tachometer that lost 10 % of its
    reading within the tested stretch of an ideal recording left a "fold" of period 1013 V
    over ~420 V that explained 58 % of the slow error; taken out, the armature's windows read
    K 45 % low at a std of 0.1 % and a false "K fell 45.5 %" was announced."""
    fold = Fold(period_v, (0.5, 0.2), rms_v=0.8, share=0.6, residual_v=0.5, largest_v=250.0,
                span_v=420.0)  # fmt: skip
    reading = Linearity(curve_v=0.02, share=0.01, largest_v=250.0, seconds=10.0, fold=fold)
    assert reading.linear
    assert (reading.correction is fold) is taken_out


def test_a_chopper_armature_beside_a_field_bridge_is_not_taken_for_a_bridge():
    """The EMF carries the field bridge's 100 Hz ripple onto a chopper's armature voltage: the
    traction motor's read as a bridge on every mains harmonic, so the armature's linearity
    test never ran and its first windows, sampled in step with a 2.5 kHz carrier at 5 kHz,
    published Ra -32 % and K -29 % as ``ok``. Its own lines are a 6-pulse bridge's."""
    from observer.estimation.linearity import made_by_a_bridge
    from observer.estimation.motor import MOTORS
    from observer.simulation.converter import PRESETS
    from observer.simulation.simulate import simulate

    realistic = PRESETS["realistic"]
    assert realistic is not None
    chopper = realistic.replace(
        converter=dataclasses.replace(realistic.converter, armature="chopper", switching_hz=2500.0)
    )
    for drive, bridge in ((chopper, False), (realistic, True)):
        rec = simulate(
            MOTORS["traction-60v"], duration_s=3.0, sample_rate_hz=5000.0, seed=31, drive=drive,
            drive_name="realistic",
        )  # fmt: skip
        va = np.asarray(rec["va"][5000:10000], dtype=np.float64)
        assert made_by_a_bridge(va, rec.dt, winding="armature") is bridge
        assert made_by_a_bridge(
            va, rec.dt, winding="field"
        )  # every mains harmonic: both read as bridges
