"""``dcobserver simulate`` with a converter and a measurement chain: options, file, metadata,
one-line errors."""

from __future__ import annotations

import pytest

from observer.cli import main
from observer.recording import read_recording


def test_realistic_preset_writes_the_drive_into_the_metadata(tmp_path):
    out = tmp_path / "r.mcap"
    argv = ["simulate", str(out), "--duration", "1", "--rate", "5000", "--preset", "realistic"]
    assert main(argv) == 0
    meta = read_recording(out).metadata
    assert meta["drive"] == "realistic"
    assert meta["converter"]["armature"]["kind"] == "thyristor-6p"
    assert meta["converter"]["armature"]["mains_hz"] == 50.0
    assert meta["converter"]["field"]["kind"] == "bridge-1p"
    for name in ("va", "ia", "vf", "if", "omega"):
        ch = meta["chain"][name]
        assert (ch["filter"], ch["order"], ch["cutoff_hz"], ch["bits"]) == ("butter", 2, 1250, 12)
        assert ch["noise"] == 0.002
        assert set(meta["adc"][name]) == {"lsb", "offset", "bits"}
    assert meta["motor"]["name"] == "P-12"


def test_single_options_change_the_preset_per_channel(tmp_path):
    out = tmp_path / "r.csv"
    chain = tmp_path / "chain.toml"
    chain.write_text("[converter]\nmains_hz = 60.0\n[chain.omega]\nnoise = 0.0\n")
    argv = [
        "simulate", str(out), "--duration", "0.5", "--rate", "4000", "--motor", "industrial-440v",
        "--preset", "realistic", "--chain", str(chain), "--converter", "chopper",
        "--field-converter", "half-3p", "--aa-filter", "bessel4@fs/8,va=rc1@500",
        "--adc-bits", "14,ia=12", "--sample-delay", "ia=2e-5", "--averaging", "va,vf",
        "--gain-error", "ia=0.01", "--offset", "if=0.01", "--full-scale", "ia=100",
        "--switching-hz", "3000",
    ]  # fmt: skip
    assert main(argv) == 0
    meta = read_recording(out).metadata
    assert meta["converter"]["armature"] == meta["converter"]["armature"] | {
        "kind": "chopper", "switching_hz": 3000.0,
    }  # fmt: skip
    assert meta["converter"]["field"]["mains_hz"] == 60.0
    va, ia, i_f, om = (meta["chain"][c] for c in ("va", "ia", "if", "omega"))
    assert (va["filter"], va["order"], va["cutoff_hz"], va["averaging"]) == ("rc", 1, 500, True)
    assert (ia["filter"], ia["order"], ia["cutoff_hz"]) == ("bessel", 4, 500)
    assert (ia["bits"], ia["full_scale"], ia["delay_s"], ia["gain_error"]) == (12, 100, 2e-5, 0.01)
    assert i_f["offset"] == 0.01 and i_f["bits"] == 14 and om["noise_std"] == 0.0
    assert meta["adc"]["ia"]["lsb"] == 200 / 2**12
    assert meta["drive"].startswith("realistic, changed by --chain --converter")


def test_effect_outside_the_library(tmp_path):
    out = tmp_path / "r.csv"
    assert main(["simulate", str(out), "--duration", "0.5", "--effect", "emf_ripple=0.05"]) == 0
    meta = read_recording(out).metadata
    assert meta["effects"]["outside_library"] == ["emf_ripple"]
    assert meta["effects"]["physical"]["emf_ripple_per_rev"] == 8


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--aa-filter", "butter2@1500"], ["--aa-filter", "cutoff 1500 Hz", "Nyquist"]),
        (["--aa-filter", "ia=cheby1@100"], ["--aa-filter", "unknown filter 'cheby'"]),
        (["--aa-filter", "butter6@100"], ["--aa-filter", "order must be 1..4"]),
        (["--adc-bits", "0"], ["--adc-bits", "bits", "1..24"]),
        (["--adc-bits", "va=-2"], ["--adc-bits", "va.bits"]),
        (["--converter", "12-pulse"], ["--converter", "unknown converter '12-pulse'"]),
        (["--field-converter", "x"], ["--field-converter", "unknown field converter"]),
        (["--sample-delay", "ia=-1e-6"], ["--sample-delay", "ia.delay_s", ">= 0"]),
        (["--sample-delay", "if=5e-4"], ["--sample-delay", "not below one sample period"]),
        (["--full-scale", "vf=0"], ["--full-scale", "vf.full_scale", "> 0"]),
        (["--mains-hz", "0"], ["--mains-hz", "1..100000"]),
        (["--dead-time", "-1"], ["--dead-time"]),
        (["--averaging", "vx"], ["--averaging", "unknown channel 'vx'"]),
        (["--preset", "fancy"], ["--preset", "unknown preset 'fancy'"]),
        (["--chain", "/nonexistent.toml"], ["/nonexistent.toml", "not found"]),
        (["--effect", "tacho_error=0.7"], ["tacho_error"]),
    ],
)
def test_bad_drive_options_are_one_line_and_exit_2(args, words, tmp_path, capsys):
    argv = ["simulate", str(tmp_path / "r.csv"), "--duration", "0.2", "--rate", "2000", *args]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for w in words:
        assert w in err, err
    assert not (tmp_path / "r.csv").exists()


def test_the_shipped_chain_example_loads():
    from pathlib import Path

    from observer.simulation.converter import DriveSpec, load_drive_file

    example = Path(__file__).resolve().parents[2] / "config" / "drive" / "chain-example.toml"
    drive = load_drive_file(example, DriveSpec())
    assert drive.chain["va"].averaging and drive.chain["if"].delay_s == 40e-6
    drive.chain.check_rate(2000.0)
