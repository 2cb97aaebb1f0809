"""Smoke runs of the benchmark scripts in their ``--quick`` configuration.

The benchmarks themselves are never run by pytest (they take minutes and time
things); these tests check that both scripts run end to end and write outputs
that parse: the table has the expected rows and numbers, the figure is a real PNG.
pyswarms is only in the ``bench`` extra, so it is left out here either way.
"""

from __future__ import annotations

import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bench import bench_pso, paper_table, peers
from bench.common import PAPER_COLUMNS, field_step_index, p12_window
from observer.estimation import kernels

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
REPO = Path(__file__).resolve().parents[2]


def _table_rows(text: str) -> dict[str, list[str]]:
    """Markdown table rows keyed by their first cell."""
    rows = {}
    for line in text.splitlines():
        if line.startswith("| ") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            rows[cells[0]] = cells[1:]
    return rows


@pytest.mark.slow
def test_paper_table_quick_writes_table_and_png(tmp_path, capsys):
    table, figure = tmp_path / "out" / "paper_table.md", tmp_path / "out" / "convergence.png"
    code = paper_table.main(
        ["--quick", "--no-progress", "--table", str(table), "--figure", str(figure)]
    )
    assert code == 0
    rows = _table_rows(table.read_text(encoding="utf-8"))
    for name in ("Rf", "Lf", "Ra", "La", "K"):
        for block in ("paper", "swarm alone", "full estimator"):
            key = f"{name} {block}"
            assert key in rows, f"missing row {key!r}"
            assert len(rows[key]) == 1 + len(PAPER_COLUMNS)
    # The paper's numbers are carried over, and our cells are numbers near the truth.
    assert rows["Rf paper"][1:] == ["332", "185", "185", "332", "185", "185"]
    assert rows["La paper"][0] == "0.02"
    for name, truth in (("Rf", 185.0), ("Lf", 50.0), ("Ra", 3.5)):
        for cell in rows[f"{name} full estimator"][1:]:
            median = float(cell.split(" ")[0])
            assert abs(median - truth) / truth < 0.05, (name, cell)
    data = figure.read_bytes()
    assert data.startswith(PNG_SIGNATURE)
    width, height = struct.unpack(">II", data[16:24])  # IHDR
    assert width >= 400 and height >= 200
    assert len(data) > 10_000
    assert "wrote" in capsys.readouterr().out


@pytest.mark.slow
def test_bench_pso_quick_writes_report(tmp_path, capsys):
    out = tmp_path / "benchmarks.md"
    code = bench_pso.main(["--quick", "--no-progress", "--skip-pyswarms", "--output", str(out)])
    assert code == 0
    text = out.read_text(encoding="utf-8")
    rows = _table_rows(text)
    ours = rows["**this PSO: `estimate_field(polish=False)`**"]
    runs, _evals, p50, p90 = int(ours[0]), ours[1], float(ours[2]), float(ours[3])
    assert runs == 3 and 0 < p50 <= p90
    assert float(ours[4]) <= p50 and float(ours[5]) > 0  # min wall, CPU p50
    assert ours[6] == "1.0×"
    for key in (
        "equation error: ARX least squares",
        "this PSO: `pso.minimize` on `rl_swarm_costs`",
    ):
        assert key in rows
    # Section headings and the targets list are all there; pyswarms was skipped.
    for heading in ("## 1.", "## 2.", "## 3.", "## 3b.", "## 4."):
        assert heading in text
    assert "not measured (pyswarms not installed or skipped)" in text
    assert not any(k.startswith("pyswarms") for k in rows)
    # Monte Carlo rows carry a finite RMSE/CRLB for this estimator.
    ratios = re.findall(r"\| this, full \| (\w+) \| [^|]+ \| [^|]+ \| ([0-9.]+) \|", text)
    assert {name for name, _ in ratios} == {"Rf", "Lf", "Ra", "La", "K"}
    assert all(0 < float(r) < 100 for _, r in ratios)
    printed = capsys.readouterr().out
    assert "x ours" in printed and str(out) in printed


def test_peer_objectives_equal_the_compiled_cost():
    """The numpy objectives given to pyswarms compute the very same eq. (1)."""
    w = p12_window(0, n_samples=400)
    x = np.array([[2.2, 1.6], [2.3, 1.7], [2.0, 0.5]])
    ref = kernels.rl_swarm_costs(x, w.vf, w.i_f, w.dt, True)
    for make in (peers.numpy_field_cost, peers.lfilter_field_cost):
        np.testing.assert_allclose(make(w.vf, w.i_f, w.dt)(x), ref, rtol=1e-9)


def test_equation_error_is_exact_on_noise_free_field_data():
    """ZOH data without noise: the ARX regression recovers R and L exactly."""
    dt = 1e-3
    vf = np.repeat([200.0, 150.0, 250.0, 180.0], 250)
    i_f = kernels.simulate_rl(185.0, 50.0, 1.0, vf, dt)
    r, ell = peers.arx_ls_field(vf, i_f, dt)
    assert r == pytest.approx(185.0, rel=1e-8) and ell == pytest.approx(50.0, rel=1e-8)
    r, ell = peers.arx_rls_field(vf, i_f, dt)
    assert r == pytest.approx(185.0, rel=1e-4) and ell == pytest.approx(50.0, rel=1e-4)


def test_window_starts_before_a_field_step():
    w = p12_window(3, n_samples=1000)
    step = field_step_index(w.vf)
    assert step == 1000 // 4
    with pytest.raises(ValueError, match="no field-voltage step"):
        field_step_index(np.full(100, 220.0))


@pytest.mark.parametrize(
    ("script", "option"), [("paper_table", "--convergence-iterations"), ("bench_pso", "--mc-seeds")]
)
def test_scripts_have_help_and_reject_bad_arguments(script, option):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", f"bench.{script}"]
    done = subprocess.run(
        [*cmd, "--help"], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0
    assert "--quick" in done.stdout and option in done.stdout
    bad = subprocess.run(
        [*cmd, "--quick", "--no-such-option"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert bad.returncode == 2
    assert "unrecognized arguments: --no-such-option" in bad.stderr
    assert "Traceback" not in bad.stderr


@pytest.mark.slow
def test_kernel_speed_quick_reports_full_width_loops(tmp_path, capsys):
    """The fast kernel's inner loops hold one packed (ymm) FMA per FMA of a block, none scalar."""
    from bench import kernel_speed

    out = tmp_path / "kernel_speed.md"
    code = kernel_speed.main(
        ["--quick", "--skip-pyswarms", "--particles", "5", "--output", str(out)]
    )
    assert code == 0
    text = out.read_text(encoding="utf-8")
    kernel_table, float32_tables = text.split("## Float32 path")
    rows = _table_rows(kernel_table) | _table_rows(float32_tables.split("## Assembly")[1])
    for loop in ("_plain_hold", "_plain_moments", "_fit_hold", "_fit_moments"):
        found, scalar, needed, passes = rows[f"`{loop}_block`"]
        assert int(found) == int(needed) > 0 and passes == "1", loop
        assert scalar == "0", loop
    field = rows["field, held voltage"]
    assert field[0] == "5" and field[1] == "5"  # particles, FMAs per particle-sample
    assert float(field[-1]) < 1e-12  # fast against plain
    # The float32 path: timed per case, and both circuits measured against the noise.
    f32 = _table_rows(float32_tables.split("## Assembly")[0])
    assert f32["field, held voltage"][0] == "5" and float(f32["field, held voltage"][-1]) > 0
    assert "field" in f32 and "armature" in f32
    assert text.count("- Float32 path, ") == 2
    assert "wrote" in capsys.readouterr().out


@pytest.mark.slow
def test_window_work_quick_accounts_every_stage(tmp_path, capsys):
    """The work ledger sees both circuits' swarms and polishes, and the replay speed."""
    from bench import window_work

    out = tmp_path / "window_work.md"
    assert window_work.main(["--quick", "--output", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    assert "× real time" in text and "two threads" in text
    evaluations = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 9 and cells[2] in ("swarm_stage", "specification_stage", "polish_stage"):
            evaluations[cells[0], cells[2]] = (float(cells[5]), float(cells[7]), float(cells[8]))
    for circuit in ("field", "armature"):
        assert evaluations[circuit, "swarm_stage"][0] > 0  # swarm evaluations per window
        assert evaluations[circuit, "specification_stage"][1] > 0  # residuals per window
        assert evaluations[circuit, "polish_stage"][2] > 0  # residuals with the Jacobian
    assert "wrote" in capsys.readouterr().out


@pytest.mark.slow
def test_multi_motor_runs_one_daemon_process_and_reports_it(tmp_path):
    from bench import multi_motor

    out = tmp_path / "multi_motor.md"
    code = multi_motor.main(
        ["--motors", "1", "--layouts", "processes", "--rate", "2000", "--duration", "2",
         "--warmup", "1", "--output", str(out)]
    )  # fmt: skip
    assert code == 0
    text = out.read_text(encoding="utf-8")
    # A recording as long as the run, not a loop (a loop's seam is no motor's behaviour).
    assert "looped" not in text and "ideal drive" in text
    rows = _table_rows(text)
    row = rows["processes"]
    # The child daemon ran and reported; how many windows it kept up with depends on the load.
    assert row[0] == "1" and int(row[1]) >= 0 and int(row[2]) >= 0 and int(row[3]) >= 0
    assert all(float(cell) >= 0 for cell in row[4:])  # latencies (ms)
    with pytest.raises(SystemExit):
        multi_motor.parse_args(["--layouts", "fibres"])
    with pytest.raises(SystemExit):
        multi_motor.parse_args(["--recording-s", "1"])
    with pytest.raises(SystemExit):
        multi_motor.parse_args(["--preset", "steam"])
