"""replay and diagnose over many recordings: one table, on a real local Dask cluster of two
worker processes, equal to the serial run; bad files named in the table and the summary."""

from __future__ import annotations

import csv
import io
import json
import logging
import sys

import pytest

from observer.recording import read_recording, write_recording
from tests.observer.clirun import in_process

distributed = pytest.importorskip("distributed")

#: Two windows per 2 s recording (1 s windows every 0.5 s): the test is about the table.
CONFIG = """\
[observer]
hop_s = 0.5
"""
#: A quick diagnosis: one effect, a small swarm.
DIAGNOSE_FAST = ("--effects", "sensor_offset", "--particles", "8", "--iterations", "4")


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """A fleet's archive: three 2 s recordings made by `dcobserver simulate` (one of them
    with the drive and motor a daemon writes into its logs' metadata) in nested folders,
    a text file named .mcap, an MCAP cut before its first block, and a CSV with no rows."""
    root = tmp_path_factory.mktemp("archive")
    (root / "shovel7" / "hoist").mkdir(parents=True)
    (root / "drive1").mkdir()
    made = {
        "drive1/a.mcap": 1,
        "drive1/b.mcap": 2,
        "shovel7/hoist/c.mcap": 3,
    }
    for name, seed in made.items():
        res = in_process(
            "simulate", str(root / name), "--preset", "ideal", "--duration", "2",
            "--seed", str(seed),
        )  # fmt: skip
        assert res.returncode == 0, res.stderr
    hoist = root / "shovel7" / "hoist" / "c.mcap"
    rec = read_recording(hoist)
    meta = {**rec.metadata, "drive_id": "shovel7", "motor_id": "hoist"}
    write_recording(type(rec)(t=rec.t, signals=dict(rec.signals), metadata=meta), hoist)
    (root / "drive1" / "notes.mcap").write_text("not a recording\n")
    (root / "drive1" / "cut.mcap").write_bytes((root / "drive1" / "a.mcap").read_bytes()[:3000])
    (root / "drive1" / "empty.csv").write_text("t,va,ia,vf,if,omega\n")
    (root / "README.txt").write_text("not picked from a folder\n")
    config = root / "fast.toml"
    config.write_text(CONFIG)
    return root


@pytest.fixture(scope="module")
def cluster():
    """A real Dask cluster: a scheduler and two single-threaded worker processes on
    127.0.0.1, closed at the end."""
    with distributed.LocalCluster(
        n_workers=2, processes=True, threads_per_worker=1, host="127.0.0.1",
        dashboard_address=None, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
        silence_logs=logging.ERROR,
    ) as local:  # fmt: skip
        yield local.scheduler_address


BAD = {"drive1/notes.mcap", "drive1/cut.mcap", "drive1/empty.csv"}


def read_table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def summary(stderr):
    line = [s for s in stderr.splitlines() if s.startswith('{"summary"')]
    assert len(line) == 1, stderr
    return json.loads(line[0])["summary"]


def replay(archive, *args):
    return in_process(
        "replay", str(archive / "drive1"), str(archive / "shovel7"),
        "--config", str(archive / "fast.toml"), "--no-progress", *args, cwd=archive,
    )  # fmt: skip


@pytest.mark.slow
def test_replay_of_an_archive_on_a_dask_cluster_equals_the_serial_run(archive, cluster):
    serial = replay(archive, "--workers", "1", "--table", "serial.csv")
    remote = replay(archive, "--scheduler", cluster, "--table", "remote.csv")
    local = replay(archive, "--workers", "2", "--table", "local.csv")
    for res in (serial, remote, local):
        # Some files could not be read: status 1, each named, never a traceback.
        assert res.returncode == 1, res.stderr
        assert "Traceback" not in res.stderr
    text = (archive / "serial.csv").read_text()
    assert (archive / "remote.csv").read_text() == text
    assert (archive / "local.csv").read_text() == text
    # The test's cluster has dask's default worker environment, the command's own does not.
    assert "its workers run with MALLOC_TRIM_THRESHOLD_=65536" in remote.stderr
    assert "MALLOC_TRIM_THRESHOLD_" not in local.stderr

    rows = read_table(archive / "serial.csv")
    assert {r["file"] for r in rows if r["error"]} == {str(archive / b) for b in BAD}
    good = [r for r in rows if not r["error"]]
    per_file = {}
    for r in good:
        per_file.setdefault(r["file"], []).append(r)
    assert sorted(per_file) == sorted(
        str(archive / n) for n in ("drive1/a.mcap", "drive1/b.mcap", "shovel7/hoist/c.mcap")
    )
    assert all(len(v) == 2 for v in per_file.values())  # windows ending at 1 and 1.5 s
    hoist = per_file[str(archive / "shovel7" / "hoist" / "c.mcap")]
    assert {(r["drive_id"], r["motor_id"]) for r in hoist} == {("shovel7", "hoist")}
    assert {r["drive_id"] for r in good} == {"drive1", "shovel7"}
    assert all(float(r["armature.K"]) > 1.0 for r in good)  # the P-12's 1.12 H
    # Rows per drive and motor: drive1's files, then shovel7/hoist.
    assert [r["drive_id"] for r in good] == sorted(r["drive_id"] for r in good)

    s = summary(serial.stderr)
    assert (s["files"], s["read"], s["bad"], s["rows"]) == (6, 3, 3, 6)
    assert sorted(s["bad_files"]) == sorted(str(archive / b) for b in BAD)
    errors = [ln for ln in serial.stderr.splitlines() if ln.startswith("dcobserver replay: error:")]
    assert sorted(ln.split(": ")[2] for ln in errors) == sorted(str(archive / b) for b in BAD)
    assert "not an MCAP file" in serial.stderr and "cut short" in serial.stderr


def test_each_row_is_the_single_file_replays_estimate(archive):
    hoist = archive / "shovel7" / "hoist" / "c.mcap"
    config = str(archive / "fast.toml")
    one = in_process("replay", str(hoist), "--config", config, "--json", "--no-progress")
    assert one.returncode == 0, one.stderr
    table = in_process(
        "replay", str(hoist), "--config", config, "--table", str(archive / "one.csv"),
        "--no-progress",
    )  # fmt: skip
    assert table.returncode == 0, table.stderr
    rows = read_table(archive / "one.csv")
    estimates = [json.loads(line) for line in one.stdout.splitlines()]
    assert len(rows) == len(estimates) == 2
    from observer.commands.archive import flatten

    for row, estimate in zip(rows, estimates, strict=True):
        assert estimate["drive_id"] == "shovel7" and estimate["motor_id"] == "hoist"
        del estimate["elapsed_ms"], estimate["units"]
        expected = {k: "" if v is None else str(v) for k, v in flatten(estimate).items()}
        assert {k: row[k] for k in expected} == expected
        assert set(row) - set(expected) == {"file", "error"}


def test_diagnose_of_an_archive_on_a_dask_cluster_equals_the_serial_run(archive, cluster):
    args = ("diagnose", str(archive / "drive1"), "--quiet", *DIAGNOSE_FAST)
    serial = in_process(*args, "--workers", "1", "--table", str(archive / "d_serial.csv"))
    remote = in_process(*args, "--scheduler", cluster, "--table", str(archive / "d_remote.csv"))
    for res in (serial, remote):
        assert res.returncode == 1, res.stderr
        assert "Traceback" not in res.stderr
    text = (archive / "d_serial.csv").read_text()
    assert (archive / "d_remote.csv").read_text() == text
    rows = read_table(archive / "d_serial.csv")
    assert len(rows) == 5  # a, b, and the three bad files
    good = {r["file"]: r for r in rows if not r["error"]}
    assert sorted(good) == [str(archive / "drive1" / "a.mcap"), str(archive / "drive1" / "b.mcap")]
    # The row is the single-file diagnosis' --json.
    single = archive / "a.json"
    res = in_process(
        "diagnose", str(archive / "drive1" / "a.mcap"), "--quiet", *DIAGNOSE_FAST,
        "--json", str(single),
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    result = json.loads(single.read_text())
    row = good[str(archive / "drive1" / "a.mcap")]
    assert row["verdict"] == result["verdict"]
    for circuit, names in (("field", ("R", "L")), ("armature", ("R", "L", "K"))):
        for name in names:
            assert row[f"{circuit}.{name}"] == str(result["baseline"][circuit][name])
            assert row[f"{circuit}.std.{name}"] == str(result["baseline"][circuit]["std"][name])
    assert summary(serial.stderr)["bad"] == 3


def test_parquet_holds_the_csv_table(archive):
    pq = pytest.importorskip("pyarrow.parquet")
    args = ("--workers", "1")
    assert replay(archive, *args, "--table", "t.parquet").returncode == 1
    assert replay(archive, *args, "--table", "t.csv").returncode == 1
    table = pq.read_table(archive / "t.parquet").to_pylist()
    rows = read_table(archive / "t.csv")
    assert len(table) == len(rows) == 9
    assert list(table[0]) == list(rows[0])
    for p, c in zip(table, rows, strict=True):
        assert p["file"] == c["file"] and p["error"] == c["error"]
        assert (p["armature.K"] is None) == (c["armature.K"] == "")
        if p["armature.K"] is not None:
            assert p["armature.K"] == float(c["armature.K"])


def test_without_the_extra_parquet_and_scheduler_are_one_line_and_the_files_run_serially(
    archive, monkeypatch
):
    monkeypatch.setitem(sys.modules, "pyarrow", None)  # as if not installed
    monkeypatch.setitem(sys.modules, "distributed", None)
    res = replay(archive, "--table", "x.parquet")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        "dcobserver replay: error: --table x.parquet: Parquet needs pyarrow, which is not "
        "installed: pip install 'dcobserver[fleet]' (or name the table .csv)"
    ]
    res = replay(archive, "--scheduler", "tcp://127.0.0.1:1")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        "dcobserver replay: error: --scheduler needs dask.distributed, which is not "
        "installed: pip install 'dcobserver[fleet]'"
    ]
    # Only the bad files, for speed: run one after the other, with a warning saying so.
    bad = [str(archive / b) for b in sorted(BAD)]
    res = in_process("replay", *bad, "--workers", "2", "--no-progress")
    assert res.returncode == 1
    assert "dask.distributed is not installed: the 3 files run one after the other" in res.stderr
    rows = list(csv.DictReader(io.StringIO(res.stdout)))  # no --table: CSV on stdout
    assert sorted(r["file"] for r in rows) == bad and all(r["error"] for r in rows)


def test_inputs_that_name_nothing_and_options_for_one_file_are_one_line(archive, tmp_path):
    cases = [
        (("replay", str(archive / "nothing" / "*.mcap")), "no file matches"),
        (("replay", str(tmp_path)), "a directory, not a file, and no recording"),
        (("replay", str(archive / "drive1"), "--report", "r.html"), "take one recording"),
        (("diagnose", str(archive / "drive1"), "--json", "r.json"), "take one recording"),
        (("replay", str(archive / "drive1"), "--table", "t.txt"), "name it .csv or .parquet"),
        (("replay", str(archive / "drive1"), "--table", "/no/such/t.csv"), "cannot write"),
        (("replay", str(archive / "drive1"), "--workers", "0"), "an integer >= 1"),
    ]
    for argv, text in cases:
        res = in_process(*argv, cwd=tmp_path)
        assert res.returncode == 2, (argv, res.stderr)
        lines = res.stderr.strip().splitlines()
        assert len(lines) == 1 and text in lines[0], (argv, res.stderr)


def test_an_unreachable_scheduler_is_one_line(archive, tmp_path, monkeypatch):
    from observer.commands import archive as module
    from tests.peers import free_port

    monkeypatch.setattr(module, "CONNECT_TIMEOUT_S", 1.0)  # nobody listens: no need to wait
    address = f"tcp://127.0.0.1:{free_port()}"
    res = in_process(
        "replay", str(archive / "drive1" / "a.mcap"), "--scheduler", address, cwd=tmp_path
    )
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith(f"dcobserver replay: error: --scheduler {address}: cannot connect")
