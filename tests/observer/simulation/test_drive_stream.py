"""The fake drives' endless stream with a converter and a measurement chain: no seams, and the
same samples through a real transport."""

from __future__ import annotations

import numpy as np
import pytest

from observer.estimation.motor import P12
from observer.simulation.chain import MeasurementChain
from observer.simulation.converter import PRESETS
from observer.simulation.drive_stream import DriveStream


def test_realistic_stream_is_the_same_whatever_the_takes():
    drive = PRESETS["realistic"]
    a = DriveStream(P12, sample_rate_hz=2000.0, seed=3, chunk_s=0.25, drive=drive)
    b = DriveStream(P12, sample_rate_hz=2000.0, seed=3, chunk_s=0.25, drive=drive)
    whole = a.take(1500)
    parts = np.concatenate([b.take(n) for n in (1, 499, 37, 963)])
    np.testing.assert_array_equal(parts, whole)
    assert a.index == 1500
    # quantised on the ADC grid of the realistic chain
    lsb = b._converter.channels[1].lsb
    np.testing.assert_array_equal(np.rint(whole[:, 1] / lsb) * lsb, whole[:, 1])


def test_stream_has_no_seam_at_chunk_boundaries():
    realistic = PRESETS["realistic"]
    assert realistic is not None
    drive = realistic.replace(chain=MeasurementChain())  # the converters, no front end
    stream = DriveStream(P12, sample_rate_hz=2000.0, seed=1, chunk_s=0.5, noise=0.0, drive=drive)
    x = stream.take(6000)  # 12 chunks, field rising from zero at power-up
    assert x[0, 3] == 0.0 and x[-1, 3] > 0.5 * P12.rated_field_current_a
    # the field current is a smooth lag of its voltage: no jump at any boundary
    jumps = np.abs(np.diff(x[:, 3]))
    boundaries = np.arange(1000, 6000, 1000) - 1
    assert jumps[boundaries].max() < 3 * np.median(jumps[999:]) + 1e-3


def test_fake_serial_drive_serves_the_realistic_stream(tmp_path):
    from drivers.serial_adc import SERIAL_P12_SCALE, SerialAdcSource, SerialOptions
    from tests.drivers.peers import FakeDrive, collect, concat, locate

    link = tmp_path / "tty"
    fake = FakeDrive("serial", "--link", str(link), "--rate", "2000", "--speedup", "2",
                     "--seed", "4", "--preset", "realistic")  # fmt: skip
    try:
        assert "serial fake drive" in fake.line
        with SerialAdcSource(SerialOptions(port=str(link), reconnect_max_s=0.2)) as src:
            blocks = collect(src, 400, timeout=30)
    finally:
        fake.kill()
    _, got = concat(blocks)
    first = np.array([got[c][0] for c in ("va", "ia", "vf", "if", "omega")])
    expected = DriveStream(P12, sample_rate_hz=2000.0, seed=4, drive=PRESETS["realistic"]).take(
        20000
    )
    scale = np.asarray(SERIAL_P12_SCALE)
    k = locate(first, expected, scale)
    n = min(200, got["va"].size)
    for c, name in enumerate(("va", "ia", "vf", "if", "omega")):
        np.testing.assert_allclose(got[name][:n], expected[k : k + n, c], atol=scale[c] * 0.51)


def test_fake_drive_rejects_a_bad_chain_in_one_line(capsys):
    from observer.cli import main

    assert main(["fake-drive", "serial", "--aa-filter", "ia=bessel3@1500", "--rate", "2000"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--aa-filter" in err and "Nyquist" in err and len(err.splitlines()) == 1


def test_fake_drive_help_shows_the_chain_options(capsys):
    from observer.cli import main

    with pytest.raises(SystemExit):
        main(["fake-drive", "modbus", "--help"])
    out = capsys.readouterr().out
    assert "--aa-filter" in out and "--preset" in out and "realistic" in out
