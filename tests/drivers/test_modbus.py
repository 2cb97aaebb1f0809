"""Modbus adapter: register decoding, and polling a fake drive's pymodbus server in a subprocess."""

from __future__ import annotations

import socket
import struct

import numpy as np
import pytest

from drivers import source_class
from drivers.fake_drive import MODBUS_INT16_BASE, MODBUS_OMEGA_INT32
from drivers.modbus import ModbusOptions, ModbusSource, RegisterSpec
from drivers.serial_adc import SERIAL_P12_SCALE
from observer.config import ConfigError
from observer.estimation import estimate_recording
from observer.estimation.motor import P12
from tests.drivers.contract import SourceContract
from tests.drivers.peers import (
    FakeDrive,
    bridged_recording,
    collect,
    concat,
    expected_stream,
    locate,
    sample_indices,
    wait_for,
)

RATE = 200.0


def _port(fake: FakeDrive) -> int:
    return int(fake.line.split(" on ", 1)[1].split(",", 1)[0].rsplit(":", 1)[1])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def fake_modbus():
    started: list[FakeDrive] = []

    def start(*args: str) -> tuple[FakeDrive, int]:
        fake = FakeDrive("modbus", "--rate", str(RATE), *args)
        started.append(fake)
        return fake, _port(fake)

    yield start
    for fake in started:
        fake.kill()


def _source(port: int, **kw) -> ModbusSource:
    kw.setdefault("reconnect_max_s", 0.2)
    return ModbusSource(ModbusOptions(port=port, **kw))


class TestModbusContract(SourceContract):
    min_samples = 50

    def make_source(self, request, tmp_path):
        fake = FakeDrive("modbus", "--port", "0", "--speedup", "2")
        request.addfinalizer(fake.kill)
        return _source(_port(fake), poll_rate_hz=1000)


@pytest.mark.parametrize(
    ("spec", "words", "value"),
    [
        (RegisterSpec("va", 0, "int16", scale=0.01), [0xFF38], -2.0),
        (RegisterSpec("va", 0, "uint16", scale=0.5, offset=1.0), [0xFF38], 32669.0),
        (RegisterSpec("va", 0, "int32"), [0xFFFF, 0xFFFE], -2.0),
        (RegisterSpec("va", 0, "int32", word_order="little"), [0xFFFE, 0xFFFF], -2.0),
        (RegisterSpec("va", 0, "uint32"), [0x0001, 0x0000], 65536.0),
        (RegisterSpec("va", 0, "float32"), list(struct.unpack(">HH", struct.pack(">f", 1.5))), 1.5),
    ],
)
def test_register_types_scale_and_word_order(spec, words, value):
    assert spec.decode(words, "big") == pytest.approx(value)


def test_register_map_from_config_and_its_errors(tmp_path):
    assert source_class("modbus") is ModbusSource
    table = {
        "port": 1502,
        "registers": [
            {"channel": "va", "address": 20, "type": "int16", "scale": 0.01},
            {"channel": "omega", "address": 30, "type": "int32", "word_order": "little"},
        ],
    }
    src = ModbusSource.from_config(table, source="m.toml", base_dir=tmp_path)
    assert src.options.registers[1] == RegisterSpec("omega", 30, "int32", word_order="little")
    bad_type = {"registers": [{"channel": "va", "address": 0, "type": "int8"}]}
    with pytest.raises(ConfigError, match="int8"):
        ModbusSource.from_config(bad_type, source="m.toml", base_dir=tmp_path)
    wide = {"registers": [{"channel": "va", "address": 0}, {"channel": "ia", "address": 200}]}
    with pytest.raises(ConfigError, match="span"):
        ModbusSource.from_config(wide, source="m.toml", base_dir=tmp_path)
    twice = {"registers": [{"channel": "va", "address": 0}, {"channel": "va", "address": 1}]}
    with pytest.raises(ConfigError, match="at most once"):
        ModbusSource.from_config(twice, source="m.toml", base_dir=tmp_path)


def test_end_to_end_field_and_resistances_at_a_modbus_poll_rate(fake_modbus):
    """200 Hz: the armature time constant (5.7 ms) is below the sample period, La unobservable.

    The field (tau 0.27 s), the armature resistance and K are estimated within
    tolerance; La is not checked (the observer must hold it at such rates).
    A poller on a busy host misses a sample now and then (counted in
    ``dropped``); this test bridges those gaps by interpolation and checks
    that they are few and exactly the ones counted.
    """
    # The ideal drive: the adapter's path end to end. The realistic one's field bridge ripples
    # at 100 Hz, this drive's Nyquist frequency, which the estimator does not bound yet (Lf
    # +3.5 % at 0.5 % std on some polls): a known miss of the drive-chain issue, not of Modbus.
    _, port = fake_modbus("--port", "0", "--seed", "4", "--preset", "ideal")
    with _source(port, poll_rate_hz=1000) as src:
        blocks = collect(src, int(5 * RATE), timeout=20)
        health = src.health()
    rec, missing = bridged_recording(blocks, RATE)
    assert missing == health["dropped"]
    # How many a poller misses is the host's load (on this shared 2-core machine up to 40 %
    # while other suites run); the rate is measured in bench/adapters_throughput.py. Here the
    # gaps must be counted exactly and leave enough to estimate from.
    assert missing < 0.5 * rec.n_samples, f"too many gaps: {health}"
    assert health["repeated_polls"] > 0  # polled faster than the drive updates
    est = estimate_recording(rec)
    f, a = est["field"], est["armature"]
    assert f.resistance_ohm == pytest.approx(P12.field_resistance_ohm, rel=0.01)
    assert f.inductance_h == pytest.approx(P12.field_inductance_h, rel=0.03)
    assert a.resistance_ohm == pytest.approx(P12.armature_resistance_ohm, rel=0.02)
    assert a.emf_constant_h == pytest.approx(P12.emf_constant_h, rel=0.01)


@pytest.mark.slow
@pytest.mark.slow
def test_int16_and_little_endian_int32_registers_decode_to_the_simulated_values(fake_modbus):
    _, port = fake_modbus("--port", "0", "--seed", "7")
    regs = [
        RegisterSpec("sequence", 0, "uint16"),
        RegisterSpec("time_us", 1, "uint32"),
        *(
            RegisterSpec(c, MODBUS_INT16_BASE + k, "int16", scale=SERIAL_P12_SCALE[k])
            for k, c in enumerate(("va", "ia", "vf", "if"))
        ),
        RegisterSpec("omega", MODBUS_OMEGA_INT32, "int32", scale=1e-4, word_order="little"),
    ]
    with _source(port, poll_rate_hz=800, registers=regs) as src:
        blocks = collect(src, 150, timeout=20)
    t, sig = concat(blocks)
    expected = expected_stream(RATE, 3000, seed=7)
    scale = np.array(SERIAL_P12_SCALE[:4])
    quantised = np.column_stack(
        [np.rint(expected[:, :4] / scale) * scale, np.rint(expected[:, 4] * 1e4) * 1e-4]
    )
    got = np.column_stack([sig[c] for c in ("va", "ia", "vf", "if", "omega")])
    k = locate(got[0], quantised, tol=np.array([*scale, 1e-4]) * 0.01) + sample_indices(t, RATE)
    np.testing.assert_allclose(got, quantised[k], rtol=0, atol=1e-9)


def test_exception_responses_are_counted_never_fatal(fake_modbus):
    _, port = fake_modbus("--port", "0", "--exception-every", "5")
    with _source(port, poll_rate_hz=500) as src:
        collect(src, 150, timeout=20)
        health = src.health()
    assert health["exception_responses"] >= health["polls"] // 5 - 2
    assert health["errors"] == health["exception_responses"] > 0
    assert health["reconnects"] == 0 and health["connected"]
    assert "exception 6" in health["last_error"]


def test_timeouts_are_counted_and_the_connection_is_renewed(fake_modbus):
    _, port = fake_modbus("--port", "0", "--stall-every", "30", "--stall-s", "0.3")
    with _source(port, poll_rate_hz=500, timeout_s=0.1) as src:
        src.read(timeout=5)
        wait_for(lambda: src.health()["timeouts"] >= 2, 20, "two timeouts")
        before = src.health()["samples"]
        collect(src, 50, timeout=20)
        health = src.health()
    assert health["reconnects"] >= 2 and health["errors"] >= 2
    assert health["samples"] >= before + 50


@pytest.mark.slow
@pytest.mark.slow
def test_server_disappears_and_comes_back(fake_modbus):
    port = _free_port()
    first, _ = fake_modbus("--port", str(port), "--seed", "1")
    with _source(port, poll_rate_hz=500, timeout_s=0.1) as src:
        collect(src, 50, timeout=20)
        first.kill()
        wait_for(lambda: not src.health()["connected"], 10, "the source to notice")
        fake_modbus("--port", str(port), "--seed", "2")
        wait_for(lambda: src.health()["reconnects"] >= 1, 20, "the reconnect")
        blocks = collect(src, 50, timeout=20)
        health = src.health()
    assert health["connected"] and health["errors"] >= 1
    t, _ = concat(blocks)
    assert np.all(np.diff(t) > 0)


def test_consumer_slower_than_polling_overruns_are_counted(fake_modbus):
    _, port = fake_modbus("--port", "0", "--speedup", "2")
    with _source(port, poll_rate_hz=1000, buffer_samples=40) as src:
        src.read(timeout=5)
        wait_for(lambda: src.health()["received_samples"] >= 200, 20, "200 samples polled")
        src.close()  # stops the pump: the counters are final
        health = src.health()
    assert health["overrun_samples"] > 0
    assert health["dropped"] >= health["overrun_samples"]
    buffered = src.buffered
    assert 0 < buffered <= 40
    assert health["samples"] + health["overrun_samples"] + buffered == health["received_samples"]


@pytest.mark.slow
@pytest.mark.slow
def test_rtu_framing_through_a_serial_url(fake_modbus):
    """RTU frames (CRC-16/MODBUS) over pyserial's socket:// URL to an RTU-framing server."""
    _, port = fake_modbus("--port", "0", "--framer", "rtu", "--seed", "3")
    options = ModbusOptions(
        transport="rtu", serial_port=f"socket://127.0.0.1:{port}", poll_rate_hz=50,
        timeout_s=0.3, reconnect_max_s=0.2,
    )  # fmt: skip
    with ModbusSource(options) as src:
        blocks = collect(src, 5, timeout=20)
        health = src.health()
    assert health["errors"] == 0 and health["polls"] >= 5
    t, sig = concat(blocks)
    expected = expected_stream(RATE, 3000, seed=3)
    got = np.column_stack([sig[c] for c in ("va", "ia", "vf", "if", "omega")])
    k = locate(got[0], expected.astype(np.float32), tol=np.full(5, 1e-6))
    np.testing.assert_array_equal(got[0], expected[k].astype(np.float32))


def test_without_counter_and_clock_every_poll_is_a_sample_on_host_time(fake_modbus):
    import time

    _, port = fake_modbus("--port", "0")
    regs = [RegisterSpec(c, 3 + 2 * k, "float32") for k, c in enumerate(("va", "ia"))]
    before = time.monotonic_ns()
    with _source(port, poll_rate_hz=400, registers=regs) as src:
        blocks = collect(src, 100, timeout=20)
    health = src.health()
    after = time.monotonic_ns()
    t, sig = concat(blocks)
    assert set(sig) == {"va", "ia"}
    assert before < t[0] and t[-1] < after and np.all(np.diff(t) > 0)
    assert health["received_samples"] == health["polls"] and health["repeated_polls"] == 0
