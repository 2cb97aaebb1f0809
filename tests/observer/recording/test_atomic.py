"""observer.recording.atomic: output files appear whole or not at all."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from observer.recording import (
    AtomicFile,
    RecordingError,
    atomic_open,
    check_writable,
    is_temporary,
    mcap_writer,
    read_recording,
    write_recording,
)
from observer.recording.atomic import final_path, temporary_path
from tests.observer.recording.helpers import make_recording


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if is_temporary(p))


def test_atomic_open_writes_under_the_final_name_only_when_complete(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    with atomic_open(target, "w") as f:
        f.write("{}\n")
        assert not target.exists()  # not yet: the bytes are under the temporary name
        assert len(_leftovers(tmp_path)) == 1
    assert target.read_text() == "{}\n"
    assert _leftovers(tmp_path) == []


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt()])
def test_an_error_while_writing_keeps_the_old_file_and_no_temporary(
    tmp_path: Path, error: BaseException
) -> None:
    target = tmp_path / "report.html"
    target.write_text("old")
    with pytest.raises(type(error)):
        with atomic_open(target, "w") as f:
            f.write("half of the new")
            raise error
    assert target.read_text() == "old"
    assert _leftovers(tmp_path) == []


def test_no_overwrite_refuses_an_existing_file_and_cleans_up(tmp_path: Path) -> None:
    target = tmp_path / "x.recovered.mcap"
    out = AtomicFile(target, overwrite=False)
    out.stream.write(b"new")
    target.write_bytes(b"appeared meanwhile")
    with pytest.raises(FileExistsError):
        out.commit()
    assert target.read_bytes() == b"appeared meanwhile"
    assert _leftovers(tmp_path) == []
    fresh = tmp_path / "fresh.mcap"
    with AtomicFile(fresh, overwrite=False) as out:
        out.stream.write(b"ok")
    assert fresh.read_bytes() == b"ok"
    assert _leftovers(tmp_path) == []


def test_discard_and_dropping_an_uncommitted_file_leave_nothing(tmp_path: Path) -> None:
    a = AtomicFile(tmp_path / "a.bin")
    a.stream.write(b"x")
    a.discard()
    a.discard()  # idempotent
    b = AtomicFile(tmp_path / "b.bin")
    del b
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="already"):
        a.commit()


def test_temporary_names_are_hidden_in_the_same_folder_and_map_back(tmp_path: Path) -> None:
    final = tmp_path / "log-2024.mcap"
    temp = temporary_path(final)
    assert temp.parent == final.parent and temp.name.startswith(".")
    assert is_temporary(temp) and not is_temporary(final)
    assert final_path(temp) == final and final_path(final) == final
    assert temporary_path(final) != temp  # fresh each time


def test_the_file_mode_follows_the_umask_not_0600(tmp_path: Path) -> None:
    with atomic_open(tmp_path / "r.json", "w") as f:
        f.write("1")
    assert (tmp_path / "r.json").stat().st_mode & 0o044  # group/other may read, as open() gives


def test_check_writable_fails_fast_and_leaves_nothing(tmp_path: Path) -> None:
    check_writable(tmp_path / "ok.html")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(FileNotFoundError):
        check_writable(tmp_path / "no-such-folder" / "x.html")
    a_file = tmp_path / "plain.txt"
    a_file.write_text("")
    with pytest.raises(NotADirectoryError):
        check_writable(a_file / "x.html")
    with pytest.raises(IsADirectoryError):
        check_writable(tmp_path)


@pytest.mark.parametrize("name", ["rec.csv", "rec.csv.gz", "rec.mcap"])
def test_an_interrupted_recording_write_leaves_the_previous_file(
    tmp_path: Path, name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / name
    old = make_recording(50)
    write_recording(old, path)
    new = make_recording(300_000)

    # Interrupt the write half-way, as Ctrl-C would.
    if name.endswith(".mcap"):
        calls = {"n": 0}
        real = mcap_writer.sample_block_proto

        def interrupted(*a, **k):  # type: ignore[no-untyped-def]
            calls["n"] += 1
            if calls["n"] == 20:
                raise KeyboardInterrupt
            return real(*a, **k)

        monkeypatch.setattr(mcap_writer, "sample_block_proto", interrupted)
    else:
        from observer.recording import csv_format

        monkeypatch.setattr(csv_format, "_CSV_WRITE_ROWS", 1000)
        real_repr = repr
        count = {"n": 0}

        def interrupted_repr(x: object) -> str:
            count["n"] += 1
            if count["n"] == 50_000:
                raise KeyboardInterrupt
            return real_repr(x)

        monkeypatch.setattr(csv_format, "repr", interrupted_repr, raising=False)
    with pytest.raises(KeyboardInterrupt):
        write_recording(new, path)
    assert read_recording(path) == old
    assert _leftovers(tmp_path) == []


def test_a_recording_write_into_a_missing_folder_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot write"):
        write_recording(make_recording(20), tmp_path / "missing" / "r.csv")


def test_gzip_output_names_the_final_file_not_the_temporary(tmp_path: Path) -> None:
    path = tmp_path / "named.csv.gz"
    write_recording(make_recording(20), path)
    assert b"named.csv" in path.read_bytes()[:40]
    assert b"partial" not in path.read_bytes()[:40]
    assert np.isfinite(read_recording(path).t).all()


def test_leave_keeps_the_partial_file_under_its_temporary_name(tmp_path: Path) -> None:
    out = AtomicFile(tmp_path / "log.mcap")
    out.stream.write(b"an hour of log before the disk filled")
    assert out.leave() == out.temp_path and out.closed
    del out  # dropping it must not remove what was left
    (left,) = tmp_path.iterdir()
    assert is_temporary(left) and final_path(left) == tmp_path / "log.mcap"
    assert left.read_bytes().startswith(b"an hour")
