"""Aliased lines of a window's voltage: found by the current's answer, removed from both."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation.lines import aliased_lines, notch, settle_samples

R, L = 3.5, 0.02  # the P-12's armature


def impedance(f: float) -> complex:
    return complex(R, 2 * np.pi * f * L)


def sampled_winding(line_hz: float, fs: float = 5000.0, seconds: float = 1.0, seed: int = 0):
    """Voltage and current samples of an RL winding driven by a slow wave and a line at
    ``line_hz`` (steady state, exact), sampled instantaneously at ``fs``: a line above
    ``fs/2`` lands at its alias in both, each at its true size."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * fs)) / fs
    v = np.zeros_like(t)
    i = np.zeros_like(t)
    for f, amp in ((3.0, 40.0), (line_hz, 30.0)):
        z = impedance(f)
        v += amp * np.sin(2 * np.pi * f * t)
        i += amp / abs(z) * np.sin(2 * np.pi * f * t - np.angle(z))
    return v + rng.normal(0, 0.05, t.size), i + rng.normal(0, 0.002, t.size)


def test_a_line_seen_at_its_alias_is_found_by_the_current_it_draws():
    """4 kHz sampled at 5 kHz lands at 1 kHz, where the winding would draw four times the
    current it does: aliased. A true 1 kHz line draws what 1 kHz draws: kept."""
    v, i = sampled_winding(4000.0)
    bands = aliased_lines(v, i, 1 / 5000.0, impedance)
    assert len(bands) == 1
    lo, hi = bands[0]
    assert lo < 1000.0 < hi and hi - lo < 20.0
    v, i = sampled_winding(1000.0)
    assert aliased_lines(v, i, 1 / 5000.0, impedance) == []


def test_a_voltage_without_lines_has_none_to_remove():
    rng = np.random.default_rng(1)
    v = np.cumsum(rng.normal(0, 1, 5000))
    i = v / R
    assert aliased_lines(v, i, 1 / 5000.0, impedance) == []
    assert aliased_lines(v[:10], i[:10], 1 / 5000.0, impedance) == []


def test_the_notch_removes_its_band_and_leaves_the_rest_after_its_ringing():
    fs = 5000.0
    t = np.arange(5000) / fs
    slow = 20.0 + 40.0 * t + 5.0 * np.sin(2 * np.pi * 7 * t)
    for line_hz in (1000.0, 1000.3):  # on a bin, and between bins
        x = slow + 30.0 * np.sin(2 * np.pi * line_hz * t)
        bands = [(995.0, 1005.0)]
        out = notch(x, 1 / fs, bands)
        edge = settle_samples(bands, 1 / fs)
        assert 0 < edge < 500
        np.testing.assert_allclose(out[edge:-edge], slow[edge:-edge], atol=0.2)
    np.testing.assert_array_equal(notch(x, 1 / fs, []), x)
    assert settle_samples([], 1 / fs) == 0


def _armature_without_and_with_notch(drive: str, duration_s: float, seed: int):
    """The P-12's armature behind ``drive`` (the realistic chain), 5 kHz: estimated with the
    aliased lines kept (``notch_aliased=False``) and as the estimator does."""
    from bench.accuracy_rates import drive_spec
    from observer.estimation import estimate_armature
    from observer.estimation.motor import P12
    from observer.simulation.simulate import simulate

    fs = 5000.0
    rec = simulate(
        P12, duration_s=duration_s, sample_rate_hz=fs, seed=seed, drive=drive_spec(drive),
        drive_name=drive,
    )  # fmt: skip
    s = [np.asarray(rec.signals[c]) for c in ("va", "ia", "if", "omega")]
    kw = dict(rng=0, n_particles=30, max_iterations=30)
    return (
        estimate_armature(*s, 1 / fs, notch_aliased=False, **kw),
        estimate_armature(*s, 1 / fs, **kw),
    )


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.slow
def test_the_chopper_at_5_khz_no_longer_reads_its_aliased_pulses_as_inductance(seed):
    """The P-12 behind a chopper (pulses at 4 kHz), 2nd-order filters at fs/4, sampled at
    5 kHz: the pulses' line at 1 kHz took La 16 % high over every recording; without it La
    is within the issue's 5 %."""
    from observer.estimation.motor import P12

    before, after = _armature_without_and_with_notch("chopper", 10.0, seed)
    la = P12.armature_inductance_h
    assert before.inductance_h / la - 1 > 0.08
    assert abs(after.inductance_h / la - 1) < 0.05
    assert abs(after.resistance_ohm / P12.armature_resistance_ohm - 1) < 0.02
    assert abs(after.emf_constant_h / P12.emf_constant_h - 1) < 0.01
    # Its std says how far it may be: within 2.5 std.
    assert abs(after.inductance_h - la) < 2.5 * after.std["L"]


def test_a_bridge_whose_jumps_are_resolved_is_estimated_as_before():
    """A thyristor bridge's ripple below Nyquist is the winding's own (its jumps resolved):
    no second pass, the estimate the same to the last digit."""
    plain, again = _armature_without_and_with_notch("thyristor", 4.0, 3)
    assert again.n_samples == plain.n_samples
    assert (again.resistance_ohm, again.inductance_h) == (plain.resistance_ohm, plain.inductance_h)
