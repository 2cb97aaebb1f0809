"""Front ends: the filter grammar, responses, and the relative front end applied to samples."""

from __future__ import annotations

import numpy as np
import pytest

from observer.config import ChainConfig, ChannelFrontEnd
from observer.estimation.frontend import (
    FrontEnd,
    apply_relative,
    check_against_rate,
    edge_samples,
    filter_sections,
    parse_filter,
    parse_front_end,
    sections_response,
    winding_front_ends,
)


@pytest.mark.parametrize("kind", ["butter", "bessel", "rc"])
@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_every_filter_is_3db_down_at_its_cutoff(kind, order):
    h = sections_response(filter_sections(kind, order, 500.0), np.array([0.0, 500.0]))
    assert abs(h[0]) == pytest.approx(1.0)
    assert abs(h[1]) == pytest.approx(1 / np.sqrt(2), rel=2e-3)


@pytest.mark.parametrize(
    ("text", "fields"),
    [
        ("none", ("none", 0, None, None)),
        ("butter2@fs/4", ("butter", 2, None, 0.25)),
        ("RC1 @ 500Hz", ("rc", 1, 500.0, None)),
        ("bessel4@1250", ("bessel", 4, 1250.0, None)),
    ],
)
def test_the_filter_grammar(text, fields):
    got = parse_filter(text)
    assert (got["filter"], got["order"], got["cutoff_hz"], got["cutoff_per_fs"]) == fields


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("cheby2@500", "unknown filter 'cheby'"),
        ("butter@500", "has no order"),
        ("butter5@500", "order must be 1..4"),
        ("butter2", "has no cutoff"),
        ("butter2@-3", "cutoff must be > 0"),
        ("butter2@fs/0", "divisor must be > 0"),
        ("butter2@fast", "is not a number"),
    ],
)
def test_bad_filters_get_a_one_line_reason(text, message):
    with pytest.raises(ValueError, match=message):
        parse_filter(text)


def test_a_front_end_must_fit_the_sample_rate():
    check_against_rate(parse_front_end("butter2@fs/4"), 2000.0, "chain.va")
    with pytest.raises(ValueError, match="chain.va: cutoff 1500 Hz is at or above the Nyquist"):
        check_against_rate(parse_front_end("rc1@1500"), 2000.0, "chain.va")
    with pytest.raises(ValueError, match="chain.ia: delay must be >= 0"):
        check_against_rate(FrontEnd(delay_s=1e-3), 2000.0, "chain.ia")


def test_the_relative_front_end_turns_one_channels_samples_into_the_others():
    fs, n = 2000.0, 4000
    t = np.arange(n) / fs
    rng = np.random.default_rng(2)
    freqs = rng.uniform(5, 450, 12)
    phases = rng.uniform(0, 2 * np.pi, 12)
    voltage = parse_front_end("rc1@fs/4", delay_s=40e-6)
    current = parse_front_end("butter2@fs/4")

    def seen(fe):
        h = fe.response(freqs, fs)
        return sum(
            abs(hk) * np.cos(2 * np.pi * f * t + p + np.angle(hk))
            for f, p, hk in zip(freqs, phases, h, strict=True)
        )

    out = apply_relative(seen(voltage), 1 / fs, voltage, current)
    edge = edge_samples(voltage, current, 1 / fs)
    inner = slice(edge, n - edge)
    target = seen(current)
    assert np.max(np.abs(out[inner] - target[inner])) < 0.02 * np.max(np.abs(target))
    # Equal front ends change nothing.
    same = apply_relative(target, 1 / fs, current, current)
    assert np.allclose(same, target)


def test_a_winding_has_front_ends_only_when_both_of_its_channels_are_known():
    chain = ChainConfig(va=ChannelFrontEnd("rc1@500"), ia=ChannelFrontEnd("butter2@500", 20.0))
    fe_v, fe_i = winding_front_ends(chain, "armature")
    assert (fe_v.filter, fe_v.order, fe_v.cutoff_hz) == ("rc", 1, 500.0)
    assert fe_i.delay_s == pytest.approx(20e-6)
    assert winding_front_ends(chain, "field") is None
    assert winding_front_ends(None, "armature") is None


def test_the_unknown_mismatch_is_the_pairs_shape_without_its_delay():
    """A sine at f comes back scaled by the pair's relative gain at f, and a slow one (where
    the pair is a pure delay, which the shift takes) hardly changes."""
    from observer.estimation.frontend import UNKNOWN_MISMATCH, unknown_mismatch

    fs = 2000.0
    t = np.arange(4000) / fs
    a, b = (parse_front_end(x) for x in UNKNOWN_MISMATCH)
    for f, expected in ((300.0, None), (2.0, 0.0)):
        v = np.sin(2 * np.pi * f * t)
        dv = unknown_mismatch(v, 1 / fs)
        middle = slice(500, 3500)
        gain = abs(b.response(np.array([f]), fs)[0]) / abs(a.response(np.array([f]), fs)[0])
        amplitude = np.sqrt(2 * np.mean((v + dv)[middle] ** 2))
        if expected is None:
            assert amplitude == pytest.approx(gain, rel=0.01)
            assert gain > 1.05  # the RC passes the ripple ~10 % weaker at 2 kHz
        else:
            assert np.max(np.abs(dv[middle])) < 1e-3


def test_a_configured_sampling_delay_is_the_one_the_simulator_makes():
    """A current channel sampled 0.4 periods late (a multiplexed ADC, `delay_us` in
    `[chain]`) holds the current of that later instant. Told so, the estimator aligns the
    channels itself and the relative delay left to fit is nil; it found +0.8 periods when the
    configured delay was applied as a lag (twice the misalignment, not none)."""
    from observer.estimation import estimate_armature
    from observer.estimation.frontend import winding_front_ends
    from observer.estimation.motor import P12
    from observer.simulation.converter import PRESETS
    from observer.simulation.simulate import simulate

    fs = 10_000.0
    drive = PRESETS["realistic"]
    assert drive is not None
    late = 0.4 / fs
    drive = drive.replace(chain=drive.chain.with_channel("ia", delay_s=late))
    rec = simulate(P12, duration_s=3.0, sample_rate_hz=fs, seed=2, drive=drive)
    window = slice(20_000, 30_000)
    sig = {c: np.asarray(rec[c], dtype=float)[window] for c in ("va", "ia", "if", "omega")}
    told = winding_front_ends(drive.chain.to_config(), "armature")
    assert told is not None and told[1].delay_s == pytest.approx(late)
    est = estimate_armature(
        sig["va"], sig["ia"], sig["if"], sig["omega"], 1 / fs, rng=0, front_ends=told,
        intersample="smooth", fit_shift=True,
    )  # fmt: skip
    assert abs(est.shift_samples) < 0.05


def test_sensor_gain_tolerances_combine_per_parameter():
    """R and L scale with the voltage's gain over the current's, K with the armature voltage's
    over the field current's and the speed's; nothing configured, nothing added."""
    from observer.estimation.frontend import gain_tolerances

    chain = ChainConfig(
        va=ChannelFrontEnd(gain_tolerance=0.003),
        ia=ChannelFrontEnd(gain_tolerance=0.004),
        i_f=ChannelFrontEnd(gain_tolerance=0.012),
        omega=ChannelFrontEnd(gain_tolerance=0.004),
    )
    arm = gain_tolerances(chain, "armature")
    assert arm["R"] == pytest.approx(0.005) and arm["L"] == pytest.approx(0.005)
    assert arm["K"] == pytest.approx(np.sqrt(0.003**2 + 0.012**2 + 0.004**2))
    assert gain_tolerances(chain, "field") == pytest.approx({"R": 0.012, "L": 0.012})
    assert gain_tolerances(ChainConfig(), "armature") == {}
    assert gain_tolerances(None, "field") == {}
