"""The drive simulator: determinism, metadata, and physically sane operation."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation.motor import P12, MotorParameters
from observer.simulation.simulate import NoiseLevels, simulate


def test_same_seed_same_recording_and_metadata():
    a = simulate(P12, duration_s=2.0, seed=9)
    b = simulate(P12, duration_s=2.0, seed=9)
    c = simulate(P12, duration_s=2.0, seed=10)
    for ch in a.channels:
        np.testing.assert_array_equal(a[ch], b[ch])
    assert not np.array_equal(a["ia"], c["ia"])
    assert a.metadata["motor"]["field_resistance_ohm"] == 185.0
    assert a.metadata["seed"] == 9
    assert a.n_samples == 4000 and a.sample_rate_hz == pytest.approx(2000.0)


def test_noise_free_recording_obeys_the_field_equation_exactly():
    rec = simulate(P12, duration_s=12.0, sample_rate_hz=1000.0, noise=NoiseLevels(), seed=1)
    a = np.exp(-P12.field_resistance_ohm * rec.dt / P12.field_inductance_h)
    b = (1 - a) / P12.field_resistance_ohm
    predicted = a * rec["if"][:-1] + b * rec["vf"][:-1]
    np.testing.assert_allclose(rec["if"][1:], predicted, rtol=1e-10)


def test_duty_cycle_reverses_current_and_steps_the_field(p12_recording):
    rec = p12_recording
    assert rec["ia"].min() < -0.5 * P12.rated_armature_current_a
    assert rec["ia"].max() > 1.5 * P12.rated_armature_current_a
    assert rec["omega"].max() > 0.8 * P12.rated_speed_rad_s
    assert rec["omega"].min() < -0.8 * P12.rated_speed_rad_s
    vf = rec["vf"]
    assert vf.max() > 1.3 * P12.rated_field_voltage_v  # forcing
    assert vf.min() < 0.8 * P12.rated_field_voltage_v  # weakening
    # Current limit of the drive (2x rated) is respected, give or take noise and ripple.
    assert np.abs(rec["ia"]).max() < 2.3 * P12.rated_armature_current_a


def test_invalid_arguments_are_rejected():
    with pytest.raises(ValueError, match="duration"):
        simulate(P12, duration_s=0)
    with pytest.raises(ValueError, match="noise"):
        simulate(P12, duration_s=1, noise=-1.0)
    with pytest.raises(ValueError, match="positive"):
        MotorParameters(**(P12.to_dict() | {"armature_inductance_h": 0.0}))
