"""``dcobserver simulate --effect`` and ``dcobserver diagnose`` end to end, in subprocesses.

The HTML report is opened in headless Chromium: the page must render its
verdict and all its inline plots without fetching anything.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from observer.recording import read_recording
from tests.observer.browser import CHROMIUM, MISSING, headless

REPO = Path(__file__).resolve().parents[3]


def _cli(*args: str, timeout: float = 180) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "observer.cli", *args],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.fixture(scope="module")
def brush_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag")
    rec = d / "brush.csv"
    out = _cli(
        "simulate",
        str(rec),
        "--duration",
        "10",
        "--seed",
        "1",
        "--effect",
        "brush_drop=0.3",
        "--preset",
        "ideal",
    )
    assert out.returncode == 0, out.stderr
    res = _cli(
        "diagnose", str(rec), "--json", str(d / "out.json"), "--report", str(d / "out.html"),
        "--effects", "brush_drop,armature_reaction,sensor_offset",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    return d, res


@pytest.mark.slow
def test_simulate_effect_writes_its_truth_into_the_metadata(brush_run):
    d, _ = brush_run
    rec = read_recording(d / "brush.csv")
    fx = rec.metadata["effects"]
    assert fx["names"] == ["brush_drop"]
    assert fx["magnitudes"]["brush_drop"] == 0.3
    assert fx["physical"]["brush_drop_v"] == 0.3


def test_diagnose_writes_the_json_contract(brush_run):
    d, res = brush_run
    out = json.loads((d / "out.json").read_text())
    assert out["verdict"] == "brush_drop"
    assert "verdict: brush_drop" in res.stdout
    assert set(out["baseline"]) >= {"field", "armature", "rms"}
    best = out["findings"][0]
    assert best["effect"] == "brush_drop"
    assert best["params"]["brush_drop_v"] == pytest.approx(0.3, rel=0.15)
    assert best["rms_after"] < best["rms_before"]
    assert best["evidence"]["accepted"] is True
    # Long fits show progress on stderr.
    assert "fitting" in res.stderr
    # Units: the baseline's by key, each effect parameter by its name.
    assert out["units"]["baseline"]["L"] == "H"
    assert out["units"]["params"]["brush_drop_v"] == "V"
    assert out["units"]["params"]["flux_deficit_at_peak_if"] == "1"
    assert out["warnings"] == []


@pytest.mark.skipif(CHROMIUM is None, reason=MISSING)
def test_report_renders_in_a_headless_browser(brush_run, tmp_path):
    d, _ = brush_run
    page = (d / "out.html").read_text()
    assert "http://" not in page and "https://" not in page  # self-contained
    args = headless(tmp_path / "profile")
    dom = subprocess.run(
        [*args, "--dump-dom", (d / "out.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert "Verdict: <b>brush_drop</b>" in dom.stdout
    assert dom.stdout.count('src="data:image/png;base64,') >= 4
    shot = tmp_path / "shot.png"
    res = subprocess.run(
        [*args, f"--screenshot={shot}", "--window-size=1280,2000", (d / "out.html").as_uri()],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert res.returncode == 0 and shot.exists(), res.stderr[-2000:]
    # A rendered page of plots, not a blank one: the PNG carries real content.
    assert shot.stat().st_size > 50_000


def test_bad_input_is_one_line_and_exit_2(tmp_path):
    res = _cli("simulate", str(tmp_path / "x.csv"), "--effect", "gremlins=3")
    assert res.returncode == 2 and "unknown effect 'gremlins'" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    res = _cli("simulate", str(tmp_path / "x.csv"), "--effect", "brush_drop=-1")
    assert res.returncode == 2 and "magnitude" in res.stderr
    field_only = tmp_path / "field.csv"
    assert (
        _cli("simulate", str(field_only), "--duration", "1", "--circuit", "field").returncode == 0
    )
    res = _cli("diagnose", str(field_only))
    assert res.returncode == 2 and "va" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
    res = _cli("diagnose", str(field_only), "--effects", "nonsense")
    assert res.returncode == 2 and "nonsense" in res.stderr
    # The chain comes from a dcobserver config, read strictly.
    bad = tmp_path / "bad.toml"
    bad.write_text("[chain]\nbogus = 1\n")
    res = _cli("diagnose", str(field_only), "--config", str(bad))
    assert res.returncode == 2 and "chain.bogus" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1


def test_too_short_a_recording_is_refused_in_one_line(tmp_path):
    short = tmp_path / "short.csv"
    assert _cli("simulate", str(short), "--duration", "0.5").returncode == 0
    res = _cli("diagnose", str(short))
    assert res.returncode == 2 and "too short" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1
