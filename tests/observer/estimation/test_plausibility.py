"""observer.estimation.plausibility: a recording in the wrong units, with swapped, inverted
or stuck channels, is caught before it becomes a silent estimate (issue 14)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer.config import QualityConfig
from observer.estimation import (
    MOTORS,
    check_data,
    check_estimates,
    estimate_recording,
    identify,
)
from observer.estimation.plausibility import white_noise_std
from observer.simulation.simulate import simulate

BOTH = ("field", "armature")
LIMITS = {c: QualityConfig().limits(c) for c in BOTH}


@pytest.fixture(scope="module")
def p12():
    rec = simulate(MOTORS["p12"], duration_s=3.0, sample_rate_hz=2000.0, noise=0.002, seed=3)
    return rec.t, dict(rec.signals), rec.dt


def _codes(findings):
    return [(f.severity, f.code, f.channel, dict(f.suggest)) for f in findings]


@pytest.mark.parametrize("motor", sorted(MOTORS))
@pytest.mark.parametrize(("rate", "noise"), [(1000.0, 0.002), (10000.0, 0.01)])
def test_real_motors_raise_no_alarm(motor: str, rate: float, noise: float):
    rec = simulate(MOTORS[motor], duration_s=2.0, sample_rate_hz=rate, noise=noise, seed=1)
    assert check_data(dict(rec.signals), rec.dt, BOTH, t=rec.t) == []


def test_time_in_milliseconds_or_microseconds_is_an_error_naming_the_unit(p12):
    t, s, dt = p12
    (f,) = check_data(s, dt * 1e3, BOTH, t=t * 1e3)
    assert (f.severity, f.code, dict(f.suggest)) == ("error", "sample_rate", {"t": "ms"})
    assert "milliseconds" in f.text and "2 Hz" in f.text
    (f,) = check_data(s, dt * 1e6, BOTH)
    assert f.severity == "error" and dict(f.suggest) == {"t": "us"}
    (f,) = check_data(s, dt * 1e9, BOTH)  # integer nanoseconds, as MCAP tools export them
    assert f.severity == "error" and dict(f.suggest) == {"t": "ns"} and "nanoseconds" in f.text


def test_a_slow_rate_warns_for_the_armature_not_for_a_field(p12):
    t, s, dt = p12
    (f,) = check_data(s, 1 / 50.0, BOTH)
    assert (f.severity, f.code, f.circuits) == ("warning", "sample_rate", ("armature",))
    field = {c: s[c] for c in ("vf", "if")}
    assert check_data(field, 1 / 50.0, ("field",)) == []


@pytest.mark.parametrize(
    ("channel", "factor", "severity", "unit"),
    [
        ("va", 1e3, "error", "mV"),  # 220 V read as 220 kV
        ("vf", 1e3, "error", "mV"),
        ("ia", 1e4, "warning", "mA"),  # 6 A read as 60 kA
        ("if", 1e3, "warning", "mA"),  # 1.2 A of field read as 1.2 kA
        ("omega", 60 / (2 * math.pi), "warning", "rpm"),  # rpm read as rad/s
    ],
)
def test_values_no_motor_has_name_the_likely_unit(p12, channel, factor, severity, unit):
    t, s, dt = p12
    bad = {**s, channel: s[channel] * factor}
    findings = [f for f in check_data(bad, dt, BOTH, t=t) if f.code == "peak"]
    assert [(f.severity, f.channel, dict(f.suggest)) for f in findings] == [
        (severity, channel, {channel: unit})
    ]
    assert " at t = " in findings[0].text


def test_an_absurd_value_is_an_error_that_suggests_no_unit(p12):
    t, s, dt = p12
    va = s["va"].copy()
    va[100] = 1e300
    (f,) = check_data({**s, "va": va}, dt, BOTH, t=t)
    assert f.severity == "error" and not f.suggest and "corrupt" in f.text
    with np.errstate(all="raise"):  # no overflow on the way to the message
        check_data({**s, "va": va}, dt, BOTH, t=t)


@pytest.mark.parametrize(
    ("change", "severity", "fragment"),
    [
        ({"ia": -1}, "error", "sign of ia"),
        ({"va": -1}, "error", "sign of ia (or of va)"),
        ({"if": -1}, "error", "sign of if"),
        ({"omega": -1}, "warning", "opposes va"),
    ],
)
def test_inverted_channels_are_named(p12, change, severity, fragment):
    t, s, dt = p12
    bad = {c: v * change.get(c, 1) for c, v in s.items()}
    findings = check_data(bad, dt, BOTH, t=t)
    assert findings[0].severity == severity and fragment in findings[0].text


def test_a_field_voltage_that_reads_nothing_of_its_current_is_not_called_inverted(p12):
    """A field chopper sampled bare in step with its pulses reads one phase of them: a voltage
    near zero whatever the current does. Its vf/if is a hair below zero, which was called an
    inverted sign (with ``--units if=-A`` offered); it is a voltage that does not read the
    winding, and the message says what to check instead."""
    t, s, dt = p12
    rng = np.random.default_rng(3)
    off = rng.normal(-0.01, 0.4, s["vf"].shape)  # noise around the pulses' off level
    findings = check_data({**s, "vf": off}, dt, BOTH, t=t)
    sign = [f for f in findings if f.code == "sign" and f.severity == "error"]
    assert len(sign) == 1 and sign[0].channel == "vf", findings
    assert "does not follow the field current" in sign[0].text and not sign[0].suggest
    assert "in step with its pulses" in sign[0].text


def test_milli_and_kilo_channels_upset_the_power_balance(p12):
    t, s, dt = p12
    findings = check_data({**s, "ia": s["ia"] * 1e3}, dt, BOTH, t=t)
    assert [f.code for f in findings] == ["power"], findings
    assert "ia in mA" in findings[0].text and findings[0].circuits == BOTH


def test_volts_in_kv_are_named_by_their_peak_not_only_by_the_power_balance(p12):
    t, s, dt = p12
    # The P-12's 200 V read as 0.2: below any wound field's or loaded armature's volts.
    for channel in ("va", "vf"):
        findings = check_data({**s, channel: s[channel] * 1e-3}, dt, BOTH, t=t)
        assert [(f.code, f.channel) for f in findings] == [("peak", channel)], findings
        assert f"is {channel} in kV?" in findings[0].text
        assert findings[0].suggest == {channel: "kV"} and findings[0].severity == "warning"
    # Small but real: 1.5 V across a winding whose current flows raises nothing.
    small = {**s, "va": s["va"] * (1.5 / np.max(np.abs(s["va"])))}
    assert not [f for f in check_data(small, dt, BOTH, t=t) if f.code == "peak"]


def test_stuck_channels_and_a_motor_at_standstill(p12):
    t, s, dt = p12
    findings = check_data({**s, "ia": np.full_like(s["ia"], 5.0)}, dt, BOTH)
    assert ("warning", "stuck", "ia", {}) in _codes(findings)
    findings = check_data({**s, "omega": np.zeros_like(s["omega"])}, dt, BOTH)
    assert any(f.code == "stuck" and "stands still" in f.text for f in findings)


def test_too_few_samples(p12):
    t, s, dt = p12
    short = {c: v[:50] for c, v in s.items()}
    assert [f.code for f in check_data(short, dt, BOTH)] == ["too_short"]
    (f,) = check_data({c: v[:5] for c, v in s.items()}, dt, BOTH)
    assert f.severity == "error" and "at least 10" in f.text


def test_swapped_field_and_armature_currents_leave_a_large_residual(p12):
    t, s, dt = p12
    swapped = {**s, "ia": s["if"], "if": s["ia"]}
    res = estimate_recording(_rec(t, swapped), BOTH)
    idents = {c: identify(e, LIMITS[c]) for c, e in res.items()}
    findings = check_estimates(res, idents, swapped)
    assert any(f.code == "fit" and f.circuits == ("field",) for f in findings), findings
    # ... and nothing it says is taken as identified.
    assert all(not any(i.identified.values()) for i in idents.values())


def test_an_armature_time_constant_of_seconds_points_at_the_time_unit(p12):
    t, s, dt = p12
    # t in milliseconds: tau_a 6 s, 2 Hz. (In units of 10 ms, tau_a 0.6 s: the fit's L is 8 %
    # off and the halves of the recording disagree by as much, so tau is not known well
    # enough to say it is beyond an armature's.)
    slow = _rec(t * 1000, s)
    res = estimate_recording(slow, ("armature",))
    idents = {c: identify(e, LIMITS[c]) for c, e in res.items()}
    findings = check_estimates(res, idents, s)
    tau = [f for f in findings if f.code == "time_constant"]
    assert tau and dict(tau[0].suggest) == {"t": "ms"} and "armature" in tau[0].text


def test_a_correct_recording_gives_no_estimate_warning(p12):
    t, s, dt = p12
    res = estimate_recording(_rec(t, s), BOTH)
    idents = {c: identify(e, LIMITS[c]) for c, e in res.items()}
    assert check_estimates(res, idents, s) == []


def test_white_noise_std_reads_the_noise_of_a_smooth_signal():
    rng = np.random.default_rng(0)
    x = np.sin(np.linspace(0, 6, 20000)) + 0.01 * rng.standard_normal(20000)
    assert white_noise_std(x) == pytest.approx(0.01, rel=0.05)


def _rec(t, signals):
    from observer.recording import Recording

    return Recording(t=t, signals=signals)
