"""Output files of the commands (issue 14): atomic, checked before the work, never overwritten
by surprise. Real subprocesses and real signals."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from observer.recording import is_temporary, read_recording
from tests.observer.clirun import in_process as here

ROOT = Path(__file__).resolve().parents[2]


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "observer.cli", *args]


def run(*args: str, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        _cmd(*args), cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )


def _one_line_error(res: subprocess.CompletedProcess[str], *fragments: str) -> None:
    assert res.returncode == 2, (res.returncode, res.stderr)
    assert "Traceback" not in res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.fixture(scope="module")
def cut_log(tmp_path_factory) -> Path:
    """A simulated MCAP recording cut at 70 %, as a crash leaves a log."""
    d = tmp_path_factory.mktemp("recover")
    full = d / "full.mcap"
    assert (
        run("simulate", str(full), "--duration", "10", "--preset", "ideal", cwd=d).returncode == 0
    )
    data = full.read_bytes()
    cut = d / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    return cut


def test_recover_refuses_to_overwrite_its_result_unless_forced(cut_log: Path, tmp_path: Path):
    src = tmp_path / "log.mcap"
    src.write_bytes(cut_log.read_bytes())
    first = run("recover", str(src), cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    out = tmp_path / "log.recovered.mcap"
    n = read_recording(out).n_samples
    assert n > 0
    before = out.read_bytes()
    again = run("recover", str(src), cwd=tmp_path)
    _one_line_error(again, "log.recovered.mcap exists", "--force")
    assert out.read_bytes() == before
    forced = run("recover", str(src), "--force", cwd=tmp_path)
    assert forced.returncode == 0, forced.stderr
    assert read_recording(out).n_samples == n
    assert not [p for p in tmp_path.iterdir() if is_temporary(p)]
    # The source is never touched without --in-place.
    assert src.read_bytes() == cut_log.read_bytes()


@pytest.mark.parametrize(
    ("content", "fragment"),
    [
        (b"\x89MCAP0\r\n\x01\x02", "nothing to recover"),  # 10 bytes: the magic and a cut
        (b"0123456789", "not an MCAP file"),
        (b"", "not an MCAP file"),
    ],
)
def test_recover_without_anything_to_recover_is_an_error(tmp_path: Path, content, fragment):
    src = tmp_path / "tiny.mcap"
    src.write_bytes(content)
    _one_line_error(run("recover", str(src), cwd=tmp_path), "tiny.mcap", fragment)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.mcap"]  # no empty result


def test_recover_of_a_missing_file_or_a_folder_is_one_line(tmp_path: Path):
    _one_line_error(run("recover", str(tmp_path / "nope.mcap"), cwd=tmp_path), "not found")
    _one_line_error(run("recover", str(tmp_path), cwd=tmp_path), "not a file")


def test_recover_in_place_replaces_the_file_atomically(cut_log: Path, tmp_path: Path):
    src = tmp_path / "log.mcap"
    src.write_bytes(cut_log.read_bytes())
    res = run("recover", str(src), "--in-place", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    with open(src, "rb") as fh:
        from mcap.reader import make_reader

        assert make_reader(fh).get_summary() is not None  # indexed: finished
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.mcap"]


def test_ctrl_c_during_simulate_leaves_no_partial_file(tmp_path: Path):
    """SIGINT (and SIGTERM) while the file is being written: no file under the final name
    unless it is complete, and no temporary left behind."""
    for sig, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):
        out = tmp_path / f"big-{sig.name}.csv"
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        proc = subprocess.Popen(
            _cmd("simulate", str(out), "--duration", "120", "--rate", "10000", "--preset", "ideal"),
            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 120
            # Wait for the event "writing has started": the temporary file exists.
            while not any(is_temporary(p) for p in tmp_path.iterdir()):
                assert proc.poll() is None, proc.communicate()
                assert time.monotonic() < deadline, "simulate never started writing"
                time.sleep(0.01)
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        assert "Traceback" not in err
        assert not [p for p in tmp_path.iterdir() if is_temporary(p)]
        if proc.returncode == 0:  # the write won the race: then the file is whole
            assert read_recording(out).n_samples == 1_200_000
        else:
            assert proc.returncode == code, err
            assert not out.exists()


def test_outputs_are_checked_before_the_work(tmp_path: Path):
    rec = tmp_path / "r.csv"
    assert here("simulate", str(rec), "--duration", "2", cwd=tmp_path).returncode == 0
    a_file = tmp_path / "plain.txt"
    a_file.write_text("")
    for option in ("--report", "--json"):
        target = str(tmp_path / "no-such-folder" / "out.x")
        res = here("diagnose", str(rec), option, target, cwd=tmp_path)
        _one_line_error(res, option, "no-such-folder", "cannot write")
        assert "fitting" not in res.stderr  # failed before the work, not after it
    res = here("diagnose", str(rec), "--json", str(a_file / "x.json"), cwd=tmp_path)
    _one_line_error(res, "--json", "cannot write")
    same = str(tmp_path / "same")
    _one_line_error(
        here("diagnose", str(rec), "--json", same, "--report", same, cwd=tmp_path), "same file"
    )
    res = here("simulate", str(tmp_path / "missing" / "x.mcap"), cwd=tmp_path)
    _one_line_error(res, "missing", "cannot write")
    res = here("simulate", str(tmp_path / "x.txt"), cwd=tmp_path)
    _one_line_error(res, "x.txt", ".csv")
