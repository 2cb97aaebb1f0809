"""The command line as users meet it: real subprocesses, real files, exit codes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from observer.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[2]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "observer.cli", *args],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip


@pytest.fixture(scope="module")
def p12_csv(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cli") / "p12.csv.gz"
    res = run(
        "simulate", str(path), "--duration", "8", "--rate", "2000", "--seed", "2", cwd=path.parent
    )
    assert res.returncode == 0, res.stderr
    return path


def test_every_command_has_help(tmp_path):
    res = run("--help", cwd=tmp_path)
    assert res.returncode == 0
    for name in COMMANDS:
        assert name in res.stdout
        sub = run(name, "--help", cwd=tmp_path)
        assert sub.returncode == 0, sub.stderr
        assert "usage: dcobserver " + name in sub.stdout


@pytest.mark.slow
def test_estimate_json_contract_and_accuracy(p12_csv):
    res = run("estimate", str(p12_csv), "--json", cwd=p12_csv.parent)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert set(out) == {"field", "armature", "recording", "limits", "warnings", "units"}
    for key in ("R", "L", "rms", "std", "quality"):
        assert key in out["field"] and key in out["armature"]
    assert out["units"]["R"] == "ohm" and out["units"]["kphi"] == "V*s/rad"
    assert out["warnings"] == []
    assert "K" in out["armature"]
    # The recording is the realistic drive (thyristor bridges, filters at fs/4 not told to
    # the estimator, 2 kHz, 8 s): what it calls identified is within the tolerance, and
    # every value within 2.5 std of the truth.
    truth = {("field", "R"): 185.0, ("field", "L"): 50.0, ("armature", "R"): 3.5,
             ("armature", "L"): 0.02, ("armature", "K"): 1.1215}  # fmt: skip
    tolerance = {"R": 0.01, "L": 0.05, "K": 0.01}
    for (circuit, key), true in truth.items():
        c = out[circuit]
        error = c[key] - true
        assert abs(error) <= 2.5 * c["std"][key], (circuit, key, c[key], c["std"][key])
        if c["quality"][key] == "ok":
            assert abs(error / true) < tolerance[key], (circuit, key, c[key])
    assert out["armature"]["quality"]["R"] == out["armature"]["quality"]["K"] == "ok"
    # A bridge made these voltages: the halves are not compared (its fold is put back).
    assert "operating_point_std" not in out["armature"]


@pytest.mark.slow
def test_estimate_says_when_the_halves_of_a_recording_disagree(tmp_path):
    """The 440 V motor behind a chopper at 2.5 kHz sampled at 2 kHz (its pulses' harmonics
    fold through the filters): the fits over the low- and high-voltage halves differ beyond
    their noise, and the table's notes say so with what to do."""
    import dataclasses

    from bench.accuracy_rates import drive_spec, front_end_drive
    from observer.estimation.motor import MOTORS
    from observer.recording import write_recording
    from observer.simulation.simulate import simulate

    drive = front_end_drive(drive_spec("chopper"), "butter2-untold")
    drive = drive.replace(converter=dataclasses.replace(drive.converter, switching_hz=2500.0))
    rec = simulate(
        MOTORS["industrial-440v"], duration_s=15.0, sample_rate_hz=2000.0, seed=0,
        drive=drive, drive_name="chopper",
    )  # fmt: skip
    path = tmp_path / "chopper.mcap"
    write_recording(rec, path)
    res = run("estimate", str(path), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "armature: the fits over the recording's low- and high-voltage halves" in res.stdout
    assert "averaged over each period" in res.stdout
    data = json.loads(run("estimate", str(path), "--json", cwd=tmp_path).stdout)
    assert data["armature"]["operating_point_std"]["K"] > 0


@pytest.mark.slow
def test_estimate_table_shows_truth_from_metadata(tmp_path):
    rec = tmp_path / "field.mcap"
    assert (
        run("simulate", str(rec), "--duration", "12", "--circuit", "field", cwd=tmp_path).returncode
        == 0
    )
    res = run("estimate", str(rec), "--circuit", "field", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "field" in res.stdout and "true" in res.stdout and "%" in res.stdout
    # A field-only file has no armature channels: a clear error, not a traceback.
    bad = run("estimate", str(rec), "--circuit", "armature", cwd=tmp_path)
    assert bad.returncode == 2
    assert "Traceback" not in bad.stderr
    assert "va" in bad.stderr and "field.mcap" in bad.stderr


@pytest.mark.parametrize(
    ("content", "fragments"),
    [
        ("", ["empty"]),
        ("t,va,ia\n0,1,2\n0.001,1,nan\n0.002,1,2\n", ["row 3", "'ia'", "NaN"]),
        ("t,vf,if\n0,1,2\n0.001,1,2\n0.001,1,2\n", ["row 4", "increasing"]),
        ("t,vf,if\n0,1,2\n0.001,1,2\n0.005,1,2\n0.006,1,2\n", ["row 4", "sampl"]),
        ("t,vf\n0,1\n0.001,abc\n", ["row 3", "'vf'"]),
    ],
)
def test_bad_recordings_exit_2_with_one_line(tmp_path, content, fragments):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    res = run("estimate", str(path), cwd=tmp_path)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert "bad.csv" in lines[0]
    for fragment in fragments:
        assert fragment in lines[0]


def test_bad_config_names_key_and_file(tmp_path, p12_csv):
    cfg = tmp_path / "narrow.toml"
    cfg.write_text("[estimate.field]\nR = [100.0, 300.0]\nLL = [1.0, 2.0]\n")
    res = run("estimate", str(p12_csv), "--config", str(cfg), cwd=tmp_path)
    assert res.returncode == 2
    assert "narrow.toml" in res.stderr and "estimate.field.LL" in res.stderr
    assert "Traceback" not in res.stderr


def test_config_narrows_the_search(tmp_path, p12_csv):
    cfg = tmp_path / "narrow.toml"
    cfg.write_text("[estimate.field]\nR = [150.0, 250.0]\nL = [20.0, 80.0]\n")
    res = run(
        "estimate", str(p12_csv), "--config", str(cfg), "--circuit", "field", "--json", cwd=tmp_path
    )
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["field"]["search_range"] == {"R": [150.0, 250.0], "L": [20.0, 80.0]}


@pytest.mark.slow
def test_same_seed_same_numbers_across_processes(p12_csv):
    a = run(
        "estimate", str(p12_csv), "--json", "--seed", "7", "--circuit", "field", cwd=p12_csv.parent
    )
    b = run(
        "estimate", str(p12_csv), "--json", "--seed", "7", "--circuit", "field", cwd=p12_csv.parent
    )
    assert a.returncode == b.returncode == 0
    assert json.loads(a.stdout)["field"]["R"] == json.loads(b.stdout)["field"]["R"]


def test_simulate_changes_and_thermal_time_constant(tmp_path):
    from observer.recording import read_recording

    out = tmp_path / "steps.mcap"
    res = run(
        "simulate", str(out), "--duration", "2", "--change", "Ra=+0.03@1,tach=-0.1@1.5",
        "--effect", "thermal_drift=0.2", "--thermal-tau", "60", cwd=tmp_path,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    meta = read_recording(out).metadata
    assert [c["target"] for c in meta["changes"]] == ["Ra", "tach"]
    assert meta["effects"]["physical"]["thermal_time_constant_s"] == 60.0
    assert meta["thermal"]["t_s"][0] == 0.0 and len(meta["thermal"]["theta"]) == 20
    for bad, fragment in (("Ra=0.03", "--change: 'Ra=0.03' is not TARGET"),
                          ("Q=1@1", "unknown change target 'Q'")):  # fmt: skip
        res = run("simulate", str(tmp_path / "x.mcap"), "--change", bad, cwd=tmp_path)
        assert res.returncode == 2 and fragment in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1


def test_a_reader_that_closes_the_pipe_ends_the_command_quietly(tmp_path):
    """``dcobserver replay --json rec.mcap | head -1``: the reader leaves after one line; the
    command stops with the shell's SIGPIPE status and no traceback."""
    rec = ROOT / "tests" / "replay" / "data" / "p12_3s_1khz.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "observer.cli", "replay", "--json", "--no-progress", str(rec)],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    assert json.loads(first)["index"] == 0
    proc.stdout.close()  # what `head -1` does after its line
    stderr = proc.stderr.read()
    assert proc.wait(timeout=300) == 141, stderr
    assert "Traceback" not in stderr and "BrokenPipeError" not in stderr, stderr
