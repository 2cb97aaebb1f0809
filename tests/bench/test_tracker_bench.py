"""Smoke runs of ``bench/tracker_bench.py`` on short recordings: its tables parse and say
what the issue asks (window fit -> tracked share, delays, false alarms per hour)."""

from __future__ import annotations

import pytest

from bench import tracker_bench
from observer.estimation.motor import P12
from observer.recording import write_recording
from observer.simulation.simulate import simulate


def test_accuracy_prints_window_fit_and_tracked_shares(tmp_path, capsys):
    path = tmp_path / "short.mcap"
    write_recording(simulate(P12, duration_s=5.0, seed=2), path)
    assert tracker_bench.main(["accuracy", str(path), "--after", "3"]) == 0
    out = capsys.readouterr().out
    rows = {line.split("|")[1].strip(): line for line in out.splitlines() if line.startswith("| ")}
    for name in ("Rf", "Ra", "K", "field temperature", "armature temperature"):
        assert name in rows, out
    # "window fit -> tracked (norm. error RMS)", each a number
    cell = rows["Rf"].split("|")[3].strip()
    before, _, rest = cell.partition(" -> ")
    after, norm = rest.split(" ")
    assert 0.0 <= float(before) <= 1.0 and float(after) == pytest.approx(1.0, abs=0.2)
    assert float(norm.strip("()")) > 0


def test_steps_and_false_alarm_summaries():
    runs = [
        {"target": "Ra", "detected": True, "delay_s": d, "reported": 0.03, "other_events": [],
         "identified_s": d - 0.3}
        for d in (0.8, 1.2, 2.5)
    ] + [{"target": "K", "detected": False, "delay_s": None, "reported": None,
          "other_events": ["x"]}]  # fmt: skip
    table = tracker_bench.steps_table(runs)
    assert "| Ra +3 % | 3/3 | 1.20 / 2.24 / 2.50 | 2/3 | +3.0 % | 0 | 2.20; 0.30 |" in table
    assert "| K -5 % | 0/1 | - | 0/1 |" in table
    clean = [{"duration_s": 1800.0, "windows": 100, "events": [], "replay_s": 600.0}] * 2
    line = tracker_bench.false_alarm_line(clean)
    assert line.startswith("0 events (false alarms) in 1.00 h") and "0.0 per hour" in line


@pytest.mark.slow
def test_false_alarms_run_on_the_realistic_drive():
    runs = tracker_bench.false_alarms(3.0 / 3600.0, 3.0, 1, preset="realistic", rate_hz=5000.0)
    assert [r["preset"] for r in runs] == ["realistic"] and runs[0]["windows"] > 0
    assert [r["rate_hz"] for r in runs] == [5000.0]
    assert "(realistic drive, 5000 Hz)" in tracker_bench.false_alarm_line(runs)
    with pytest.raises(SystemExit, match="--preset: unknown 'thyristor'"):
        tracker_bench.steps(1, 1, preset="thyristor")
