"""The measurement chain's description: option syntax, validation, filters, quantisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer.config import ConfigError
from observer.simulation.chain import (
    ChannelChain,
    MeasurementChain,
    filter_sections,
    frequency_response,
    parse_filter,
    parse_per_channel,
    quantise,
)
from observer.simulation.converter import (
    PRESETS,
    ConverterSpec,
    DriveSpec,
    apply_chain_table,
    load_drive_file,
)


def test_filter_syntax():
    assert parse_filter("butter2@fs/4") == {
        "filter": "butter", "order": 2, "cutoff_hz": None, "cutoff_per_fs": 0.25,
    }  # fmt: skip
    assert parse_filter("RC1@500Hz")["cutoff_hz"] == 500.0
    assert parse_filter("bessel4 @ 1e3")["cutoff_hz"] == 1000.0
    assert parse_filter("none")["filter"] == "none"
    for bad, message in [
        ("cheby2@500", "unknown filter 'cheby'"),
        ("butter5@500", "order must be 1..4"),
        ("butter@500", "no order"),
        ("butter2", "no cutoff"),
        ("butter2@-5", "must be > 0"),
        ("butter2@fs/0", "divisor"),
        ("butter2@abc", "not a number"),
    ]:
        with pytest.raises(ValueError, match=message):
            parse_filter(bad)


def test_per_channel_syntax():
    assert parse_per_channel("12", int) == {"*": 12}
    assert parse_per_channel("12, va=14,if=16", int) == {"*": 12, "va": 14, "if": 16}
    with pytest.raises(ValueError, match="unknown channel 'vb'"):
        parse_per_channel("vb=3", int)
    with pytest.raises(ValueError, match="given twice"):
        parse_per_channel("va=3,va=4", int)
    with pytest.raises(ValueError, match="ia: "):
        parse_per_channel("ia=x", int)


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"filter": "cheby", "order": 2, "cutoff_hz": 5.0}, "chain.ia.filter"),
        ({"filter": "butter", "order": 5, "cutoff_hz": 5.0}, "chain.ia.order"),
        ({"filter": "butter", "order": 0, "cutoff_hz": 5.0}, "chain.ia.order"),
        ({"filter": "butter", "order": 2}, "chain.ia.cutoff_hz"),
        ({"filter": "butter", "order": 2, "cutoff_hz": -1.0}, "chain.ia.cutoff_hz"),
        ({"bits": 0}, "chain.ia.bits"),
        ({"bits": -3}, "chain.ia.bits"),
        ({"bits": 40}, "chain.ia.bits"),
        ({"full_scale": 0.0}, "chain.ia.full_scale"),
        ({"full_scale": -2.0}, "chain.ia.full_scale"),
        ({"delay_s": -1e-6}, "chain.ia.delay_s"),
        ({"noise": -0.1}, "chain.ia.noise"),
        ({"gain_error": -1.0}, "chain.ia.gain_error"),
        ({"offset": math.nan}, "chain.ia.offset"),
    ],
)
def test_impossible_channel_values_name_their_key(changes, key):
    with pytest.raises(ValueError) as exc:
        MeasurementChain().with_channel("ia", **changes)
    message = str(exc.value)
    assert message.startswith(key + ":") and "\n" not in message


def test_rate_dependent_checks_name_their_key():
    chain = MeasurementChain().with_channel("if", filter="butter", order=2, cutoff_hz=1500.0)
    chain.check_rate(4000.0)
    with pytest.raises(ValueError, match=r"^chain\.if\.cutoff_hz: cutoff 1500 Hz is above"):
        chain.check_rate(2000.0)
    delayed = MeasurementChain().with_channel("va", delay_s=5e-4)
    delayed.check_rate(1000.0)
    with pytest.raises(ValueError, match=r"^chain\.va\.delay_s: .* not below one sample period"):
        delayed.check_rate(2000.0)
    with pytest.raises(ValueError, match=r"^chain\.va\.cutoff_per_fs"):
        MeasurementChain.uniform(ChannelChain("rc", 1, cutoff_per_fs=0.75)).check_rate(1e3)


def test_converter_spec_errors_name_their_key():
    for changes, key in [
        ({"armature": "12-pulse"}, "converter.armature"),
        ({"field": "magic"}, "converter.field"),
        ({"mains_hz": 0.0}, "converter.mains_hz"),
        ({"line_voltage_v": -400.0}, "converter.line_voltage_v"),
        ({"dead_time_s": -1.0}, "converter.dead_time_s"),
        ({"source_inductance_h": -1e-3}, "converter.source_inductance_h"),
        ({"alpha_max_deg": 80.0}, "converter.alpha_min_deg/alpha_max_deg"),
    ]:
        with pytest.raises(ValueError, match="^" + key):
            ConverterSpec(**changes)


@pytest.mark.parametrize("kind", ["butter", "bessel", "rc"])
@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_every_filter_is_3db_down_at_its_cutoff(kind, order):
    sections = filter_sections(kind, order, 700.0)
    assert np.count_nonzero(sections[:, 0]) == (order + 1) // 2
    h = frequency_response(sections, np.array([0.0, 700.0, 7000.0]))
    assert abs(h[0]) == pytest.approx(1.0, abs=1e-12)
    assert abs(h[1]) == pytest.approx(1 / math.sqrt(2), rel=2e-6)
    # and it falls off as its order beyond the cutoff
    assert abs(h[2]) < 1.3 * 10.0 ** (-order) * (1.0 if kind == "butter" else 30.0)


def test_quantise_is_exact_and_saturates():
    lsb = 2 * 7.3 / 2**12
    x = np.array([-100.0, -7.3, -0.01, 0.0, 1e-9, 3.14159, 7.29, 100.0])
    q = quantise(x, lsb, 12)
    counts = np.rint(q / lsb)
    np.testing.assert_array_equal(0.0 + lsb * counts, q)
    assert counts.min() == -2048 and counts.max() == 2047
    assert np.all(np.abs(q[2:-2] - x[2:-2]) <= lsb / 2)


def test_chain_file_keys_and_errors(tmp_path):
    chain = apply_chain_table(
        MeasurementChain(), {"filter": "butter2@fs/4", "bits": 12, "va": {"filter": "rc1@500"}}
    )
    assert chain["va"].filter == "rc" and chain["va"].cutoff_hz == 500.0
    assert chain["omega"].filter == "butter" and chain["omega"].bits == 12
    good = tmp_path / "good.toml"
    good.write_text('[converter]\narmature = "chopper"\n[chain.ia]\ndelay_s = 1e-5\n')
    drive = load_drive_file(good, DriveSpec())
    assert drive.converter.armature == "chopper" and drive.chain["ia"].delay_s == 1e-5
    for text, words in [
        ("[chain]\nbits = 0\n", ["bad.toml", "chain.bits"]),
        ("[chain.vf]\nfilter = 'butter9@500'\n", ["bad.toml", "chain.vf.filter", "1..4"]),
        ("[chain.vf]\nfull_scale = 0\n", ["bad.toml", "chain.vf.full_scale"]),
        ("[chain]\nbitz = 3\n", ["bad.toml", "unknown key 'bitz'"]),
        ("[converter]\narmature = 'x'\n", ["bad.toml", "converter.armature", "unknown"]),
        ("[converter]\nmains_hz = 'fifty'\n", ["bad.toml", "converter.mains_hz"]),
        ("[drive]\n", ["bad.toml", "unknown table [drive]"]),
        ("[chain\n", ["bad.toml", "TOML"]),
    ]:
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(ConfigError) as exc:
            load_drive_file(bad, DriveSpec())
        assert all(w in str(exc.value) for w in words), str(exc.value)
        assert "\n" not in str(exc.value)


def test_the_realistic_preset_is_what_the_issue_names():
    drive = PRESETS["realistic"]
    assert drive is not None
    assert (drive.converter.armature, drive.converter.field) == ("thyristor-6p", "bridge-1p")
    for _, ch in drive.chain.items():
        assert (ch.filter, ch.order, ch.cutoff_per_fs, ch.bits) == ("butter", 2, 0.25, 12)
        assert ch.noise is None  # the recording's noise: 0.2 % by default
    assert PRESETS["ideal"] is None
