"""EMF speed from the armature equation, and the tachometer cross-check."""

from __future__ import annotations

import pytest

from observer.config import SpeedConfig
from observer.estimation.motor import P12
from observer.service.speed import SpeedEstimate, TachometerCheck, emf_speed
from observer.simulation.simulate import NoiseLevels, simulate

PARAMS = {
    "Ra": (P12.armature_resistance_ohm, 0.0),
    "La": (P12.armature_inductance_h, 0.0),
    "K": (P12.emf_constant_h, 0.0),
}


@pytest.fixture(scope="module")
def clean():
    return simulate(P12, duration_s=6.0, sample_rate_hz=2000.0, noise=NoiseLevels(), seed=8)


def test_emf_speed_equals_the_measured_speed_on_an_ideal_machine(clean):
    for start in range(0, clean.n_samples - 2000, 1000):
        sl = slice(start, start + 2000)
        speed = emf_speed(
            clean["va"][sl], clean["ia"][sl], clean["if"][sl], clean["omega"][sl], clean.dt,
            PARAMS,
        )  # fmt: skip
        assert speed is not None
        # The plant is integrated by RK4 between samples; the discrete balance holds
        # to the integration error.
        assert speed.emf_rad_s == pytest.approx(speed.measured_rad_s, abs=2e-3 * speed.scale_rad_s)
        assert speed.std_rad_s < 1e-6  # exact parameters, no noise


def test_emf_speed_std_follows_the_parameters(clean):
    sl = slice(4000, 6000)
    rel = {"Ra": (PARAMS["Ra"][0], 0.01), "La": (PARAMS["La"][0], 0.0), "K": (PARAMS["K"][0], 0.0)}
    base = emf_speed(clean["va"][sl], clean["ia"][sl], clean["if"][sl], None, clean.dt, PARAMS)
    high = dict(PARAMS, Ra=(PARAMS["Ra"][0] * 1.01, 0.0))
    moved = emf_speed(clean["va"][sl], clean["ia"][sl], clean["if"][sl], None, clean.dt, high)
    with_std = emf_speed(clean["va"][sl], clean["ia"][sl], clean["if"][sl], None, clean.dt, rel)
    assert base is not None and moved is not None and with_std is not None
    assert base.measured_rad_s is None
    # A 1 % error of Ra moves the EMF speed by what a 1 % std of Ra says.
    assert with_std.std_rad_s == pytest.approx(abs(moved.emf_rad_s - base.emf_rad_s), rel=1e-3)


def _speed(emf, measured, scale=None):
    return SpeedEstimate(emf, 0.01, measured, abs(emf) + 5.0 if scale is None else scale)


def test_tachometer_reading_low_raises_after_alarm_s_and_clears_after_agreement():
    check = TachometerCheck(SpeedConfig(alarm_s=0.5), hop_s=0.1)
    t = 0
    for _ in range(10):
        t += 100_000_000
        assert check.update(t, _speed(150.0, 150.1)) == (False, None)
    events = []
    for _ in range(10):
        t += 100_000_000
        suspect, event = check.update(t, _speed(150.0, 135.0))
        assert suspect
        if event:
            events.append(event)
    assert len(events) == 1 and events[0]["state"] == "fault"
    # 10 % low against a margin of ~2 %: each window counts for half of alarm_s.
    assert events[0]["t_ns"] - events[0]["since_ns"] == 100_000_000  # 2 windows
    assert events[0]["relative"] == pytest.approx(-0.1)
    assert check.faulty and check.distrusts_k(None)
    # Standstill: neither raises nor clears.
    for _ in range(20):
        t += 100_000_000
        assert check.update(t, _speed(0.5, 0.0)) == (None, None)
    assert check.faulty
    cleared = [check.update(t + k * 100_000_000, _speed(-150.0, -150.0))[1] for k in range(1, 7)]
    assert [e["state"] for e in cleared if e] == ["cleared"]
    assert not check.faulty


def test_a_disagreement_just_beyond_the_margin_needs_alarm_s():
    check = TachometerCheck(SpeedConfig(alarm_s=0.5), hop_s=0.1)
    margin = 0.02 * 155.0 + 4.0 * 0.01 * 2**0.5  # tolerance * scale + n_sigma * sigma
    events = []
    for k in range(1, 11):
        suspect, event = check.update(k * 100_000_000, _speed(150.0, 150.0 - 1.2 * margin))
        assert suspect
        events += [(k, event)] if event else []
    assert [k for k, _ in events] == [5]  # five windows of 1.2 margins: 0.5 s


def test_a_measured_speed_above_the_emf_speed_is_not_a_tachometer_fault():
    """A weakened field looks like a tachometer reading high: it is K's change to report."""
    check = TachometerCheck(SpeedConfig(), hop_s=0.1)
    for k in range(1, 30):
        assert check.update(k * 100_000_000, _speed(150.0, 158.0)) == (False, None)
