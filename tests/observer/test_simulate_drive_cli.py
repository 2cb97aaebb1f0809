"""``dcobserver simulate`` with a converter and a measurement chain: options, file, metadata,
one-line errors."""

from __future__ import annotations

from pathlib import Path

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
    chain.write_text("[converter]\nmains_hz = 60.0\n[sensors.omega]\nnoise = 0.0\n")
    argv = [
        "simulate", str(out), "--duration", "0.5", "--rate", "4000", "--motor", "industrial-440v",
        "--preset", "realistic", "--chain", str(chain), "--converter", "chopper",
        "--field-converter", "half-3p", "--aa-filter", "bessel4@fs/8,va=rc1@500",
        "--adc-bits", "14,ia=12", "--delay-us", "ia=20", "--averaging", "va,vf",
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
        (["--aa-filter", "va=butter2@fs/2"], ["--aa-filter", "va.filter", "Nyquist"]),
        (["--converter", "12-pulse"], ["--converter", "unknown converter '12-pulse'"]),
        (["--field-converter", "x"], ["--field-converter", "unknown field converter"]),
        (["--delay-us", "ia=-1"], ["--delay-us", "ia.delay_us", ">= 0"]),
        (["--delay-us", "if=500"], ["--delay-us", "500 us is not below one sample period"]),
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


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[chain.ia]\nfilter = 'butter2@1500'\n", ["chain.ia.filter", "Nyquist", "--rate 2000"]),
        ("[chain.ia]\nfilter = 'cheby2@100'\n", ["'chain.ia.filter'", "unknown filter 'cheby'"]),
        ("[sensors]\nbits = 0\n", ["sensors.bits", "1..24"]),
        ("[converter]\narmature = '12-pulse'\n", ["converter.armature", "12-pulse"]),
        ("[chain]\nfilter = 'butter2@fs/4'\n", ["unknown key 'chain.filter'"]),
    ],
)
def test_a_bad_drive_file_is_one_line_naming_file_and_key(text, words, tmp_path, capsys):
    bad = tmp_path / "bad-chain.toml"
    bad.write_text(text)
    argv = ["simulate", str(tmp_path / "r.csv"), "--duration", "0.2", "--rate", "2000",
            "--chain", str(bad)]  # fmt: skip
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    for w in [str(bad), *words]:
        assert w in err, err
    assert not (tmp_path / "r.csv").exists()


def _example() -> Path:
    return Path(__file__).resolve().parents[2] / "config" / "drive" / "chain-example.toml"


def test_the_shipped_chain_example_loads():
    from observer.simulation.converter import DriveSpec, load_drive_file

    drive = load_drive_file(_example(), DriveSpec())
    assert drive.chain["va"].averaging and drive.chain["if"].delay_s == pytest.approx(40e-6)
    assert drive.chain["omega"].bits == 12 and drive.converter.armature == "thyristor-6p"
    drive.chain.check_rate(2000.0)


def test_one_chain_description_for_simulate_and_estimate(tmp_path, capsys):
    """The example's [chain] is a dcobserver config as it stands: estimate reads what simulate
    made the recording through."""
    from observer.config import load_config
    from observer.simulation.converter import DriveSpec, load_drive_file

    text = _example().read_text()
    config = tmp_path / "dcobserver.toml"
    config.write_text(text[text.index("\n[chain]") : text.index("\n[sensors]")])
    chain = load_config(config).chain
    simulated = load_drive_file(_example(), DriveSpec()).chain
    assert simulated.to_config() == chain
    assert load_drive_file(config, DriveSpec()).chain == DriveSpec().chain.with_config(chain)
    rec = tmp_path / "r.mcap"
    argv = ["simulate", str(rec), "--duration", "2", "--rate", "4000", "--chain", str(_example())]
    assert main(argv) == 0
    argv = ["estimate", str(rec), "--circuit", "field", "--config", str(config), "--json",
            "--particles", "20", "--iterations", "20"]  # fmt: skip
    assert main(argv) == 0
    assert '"field"' in capsys.readouterr().out


@pytest.mark.slow
def test_estimate_says_which_voltage_filter_the_jumps_showed(tmp_path, capsys):
    """Front ends not told: `estimate` identifies the voltage filter from the converter's jumps,
    and says so (its JSON carries it per circuit; the text names it)."""
    import json

    rec = tmp_path / "r.mcap"
    assert main(["simulate", str(rec), "--duration", "4", "--rate", "5000"]) == 0  # realistic
    capsys.readouterr()
    common = ["--particles", "20", "--iterations", "20"]
    assert main(["estimate", str(rec), "--json", *common]) == 0
    out = json.loads(capsys.readouterr().out)
    for circuit in ("field", "armature"):
        fit = out[circuit]["voltage_filter"]
        assert fit["text"].startswith("butter2@fs/"), fit  # the preset's butter2 at fs/4
        assert 0.0141 < fit["alias"] < 0.0142 * 1.2
    assert main(["estimate", str(rec), *common]) == 0
    text = capsys.readouterr().out
    assert "field voltage filter (front ends not configured): butter2@fs/" in text
    # The field's jumps are put back through it (observer.estimation.dealias); not the armature's.
    said = [ln for ln in text.splitlines() if " voltage filter " in ln]
    lines = {ln.split(" voltage filter")[0]: ln for ln in said}
    assert "its jumps put back between the samples" in lines["field"]
    assert "put back" not in lines["armature"]
