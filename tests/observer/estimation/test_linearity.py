"""A voltage reading that follows a curve of the voltage: a converter's pulses folded onto
zero frequency, seen in the armature's slow equation error and held."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from observer.estimation.linearity import (
    MIN_SECONDS,
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
    assert made_by_a_bridge(bridge.signals["vf"][:4000], bridge.dt)
    assert not made_by_a_bridge(aliased.signals["vf"][:n], aliased.dt)
    assert not made_by_a_bridge(aliased.signals["va"][:n], aliased.dt)

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
