"""The measurement chain's description: option syntax, validation, filters, quantisation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from observer.config import ChainConfig, ChannelFrontEnd, ConfigError, parse_filter
from observer.estimation.frontend import filter_sections, sections_response
from observer.simulation.chain import (
    ChannelChain,
    MeasurementChain,
    parse_per_channel,
    quantise,
)
from observer.simulation.converter import PRESETS, ConverterSpec, DriveSpec, load_drive_file


@pytest.mark.parametrize(
    "text", ["none", "butter2@fs/4", "bessel4@1250", "rc1@fs/8", "rc3@333.5", "butter1@fs/2.5"]
)
def test_a_channel_writes_its_filter_in_the_grammar_it_was_read_from(text):
    ch = ChannelChain(**parse_filter(text))
    assert parse_filter(ch.filter_text()) == parse_filter(text)


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
        ({"bits": 0}, "sensors.ia.bits"),
        ({"bits": -3}, "sensors.ia.bits"),
        ({"bits": 40}, "sensors.ia.bits"),
        ({"full_scale": 0.0}, "sensors.ia.full_scale"),
        ({"full_scale": -2.0}, "sensors.ia.full_scale"),
        ({"delay_s": -1e-6}, "chain.ia.delay_us"),
        ({"noise": -0.1}, "sensors.ia.noise"),
        ({"gain_error": -1.0}, "sensors.ia.gain_error"),
        ({"offset": math.nan}, "sensors.ia.offset"),
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
    with pytest.raises(ValueError, match=r"^chain\.if\.filter: cutoff 1500 Hz is at or above"):
        chain.check_rate(2000.0)
    with pytest.raises(ValueError, match=r"^chain\.if\.filter: cutoff 1500 Hz is at or above"):
        chain.check_rate(3000.0)  # the estimator's limit: below Nyquist
    delayed = MeasurementChain().with_channel("va", delay_s=5e-4)
    delayed.check_rate(1000.0)
    with pytest.raises(ValueError, match=r"^chain\.va\.delay_us: 500 us is not below one sample"):
        delayed.check_rate(2000.0)
    with pytest.raises(ValueError, match=r"^chain\.va\.filter"):
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
    h = sections_response(sections, np.array([0.0, 700.0, 7000.0]))
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


def test_a_drive_file_changes_only_what_it_gives(tmp_path):
    base = PRESETS["realistic"]
    assert base is not None
    good = tmp_path / "good.toml"
    good.write_text(
        '[converter]\narmature = "chopper"\n'
        '[chain.ia]\ndelay_us = 10.0\n[chain.va]\nfilter = "rc1@500"\n'
        "[sensors]\nbits = 14\n[sensors.if]\nnoise = 0.0\n"
    )
    drive = load_drive_file(good, base)
    assert (drive.converter.armature, drive.converter.field) == ("chopper", "bridge-1p")
    va, ia, i_f = drive.chain["va"], drive.chain["ia"], drive.chain["if"]
    assert (va.filter, va.order, va.cutoff_hz, va.bits) == ("rc", 1, 500.0, 14)
    assert (ia.filter, ia.cutoff_per_fs, ia.delay_s) == ("butter", 0.25, 1e-5)
    assert (i_f.noise, drive.chain["omega"].noise) == (0.0, None)


def test_a_dcobserver_config_is_a_drive_file(tmp_path):
    config = tmp_path / "dcobserver.toml"
    config.write_text('[estimate]\nparticles = 50\n[chain]\nintersample = "hold"\n'
                      '[chain.va]\nfilter = "bessel2@800"\n')  # fmt: skip
    drive = load_drive_file(config, DriveSpec())
    assert (drive.chain["va"].filter, drive.chain["va"].cutoff_hz) == ("bessel", 800.0)


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[sensors]\nbits = 0\n", ["sensors.bits", "1..24"]),
        ("[sensors.if]\nbits = 2.5\n", ["sensors.if.bits", "integer"]),
        ("[chain.vf]\nfilter = 'butter9@500'\n", ["chain.vf.filter", "1..4"]),
        ("[chain.ia]\ndelay_us = -3\n", ["chain.ia.delay_us", ">= 0"]),
        ("[sensors.vf]\nfull_scale = 0\n", ["sensors.vf.full_scale"]),
        ("[chain]\nbits = 3\n", ["unknown key 'chain.bits'"]),
        ("[chain]\nfilter = 'butter2@fs/4'\n", ["unknown key 'chain.filter'"]),
        ("[chain.ia]\ndelay_s = 1e-5\n", ["unknown key 'chain.ia.delay_s'", "delay_us"]),
        ("[sensors.ib]\nbits = 3\n", ["unknown key 'sensors.ib'"]),
        ("[converter]\narmature = 'x'\n", ["converter.armature", "unknown"]),
        ("[converter]\nmains_hz = 'fifty'\n", ["converter.mains_hz", "number"]),
        ("[converter]\nmains = 50\n", ["unknown key 'converter.mains'"]),
        ("[drive]\n", ["unknown table [drive]"]),
        ("[chain\n", ["TOML"]),
    ],
)
def test_bad_drive_files_name_the_file_and_the_key(tmp_path, text, words):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(ConfigError) as exc:
        load_drive_file(bad, DriveSpec())
    message = str(exc.value)
    assert message.startswith(str(bad)) and "\n" not in message
    assert all(w in message for w in words), message


def test_the_estimator_is_given_the_chain_the_simulator_used():
    from observer.estimation.frontend import winding_front_ends

    chain = (
        MeasurementChain.uniform(ChannelChain("butter", 2, cutoff_per_fs=0.25, bits=12))
        .with_channel(
            "va", filter="rc", order=1, cutoff_hz=500.0, cutoff_per_fs=None, averaging=True
        )
        .with_channel("ia", delay_s=2e-5, gain_error=0.01)
    )
    config = chain.to_config()
    assert config.va == ChannelFrontEnd(filter="rc1@500", delay_us=0.0, averaging=True)
    assert config.i_f == ChannelFrontEnd(filter="butter2@fs/4")
    fronts = winding_front_ends(config, "armature")
    assert fronts is not None
    for front, name in zip(fronts, ("va", "ia"), strict=True):
        ch = chain[name]
        assert (front.filter, front.order, front.cutoff_hz, front.cutoff_per_fs) == (
            ch.filter, ch.order, ch.cutoff_hz, ch.cutoff_per_fs,
        )  # fmt: skip
        assert front.delay_s == pytest.approx(ch.delay_s) and front.averaging == ch.averaging
    # and back: what the estimator knows, the simulator reads (not the sensors)
    back = MeasurementChain().with_config(config)
    assert back["ia"].delay_s == pytest.approx(2e-5) and back["ia"].gain_error == 0.0
    assert back["va"].filter_text() == "rc1@500" and back["va"].averaging
    assert MeasurementChain().with_config(ChainConfig()) == MeasurementChain()


def test_the_realistic_preset_is_what_the_issue_names():
    drive = PRESETS["realistic"]
    assert drive is not None
    assert (drive.converter.armature, drive.converter.field) == ("thyristor-6p", "bridge-1p")
    for _, ch in drive.chain.items():
        assert (ch.filter, ch.order, ch.cutoff_per_fs, ch.bits) == ("butter", 2, 0.25, 12)
        assert ch.noise is None  # the recording's noise: 0.2 % by default
    assert PRESETS["ideal"] is None
