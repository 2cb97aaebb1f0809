"""SIGKILL at random moments: every cut log is recovered at the next start, at most 1 s lost."""

from __future__ import annotations

import numpy as np
import pytest

from bench.crash_loss import kill_and_restart, make_recording
from observer.recording import read_recording
from replay.source import iter_mcap_blocks


@pytest.mark.slow
def test_sigkill_five_times_each_cut_log_recovered_automatically_at_most_1_s_lost(tmp_path):
    recording = make_recording(tmp_path)
    original = read_recording(recording)
    kills = kill_and_restart(tmp_path, recording, kills=5, speed=4.0, seed=13)
    assert len(kills) == 5
    period_ns = 500_000  # 2 kHz
    for kill in kills:
        # Recovered by the next start (mcap's indexed reader read it back), the cut one gone.
        assert kill.recovered.exists() and not kill.cut.exists() and kill.messages > 0
        assert 0.0 <= kill.lost_s <= 1.0, f"{kill.recovered.name}: {kill.lost_s:.2f} s lost"
        # What was recovered is exactly what was replayed (the recording, looping).
        blocks = list(iter_mcap_blocks(kill.recovered))
        t_ns = np.concatenate([b.t_ns for b in blocks])
        ia = np.concatenate([b.signals["ia"] for b in blocks])
        assert np.array_equal(np.diff(t_ns), np.full(t_ns.size - 1, period_ns))  # no hole
        index = (t_ns // period_ns) % original.n_samples
        assert np.array_equal(ia, original["ia"][index])
        assert all(b.scales["ia"] for b in blocks)  # stored as ADC counts
    logs = tmp_path / "logs"
    assert not list(logs.glob(".*partial*"))  # nothing left under a temporary name
    assert len(list(logs.glob("*.mcap"))) == 6  # five recovered, the last one finished
