"""read_recording / write_recording (observer/recording/__init__.py): the format by the name."""

from __future__ import annotations

from pathlib import Path

import pytest

from observer.recording import (
    RecordingError,
    read_csv,
    read_recording,
    write_recording,
)
from tests.observer.recording.helpers import (
    make_recording,
)


@pytest.mark.parametrize("name", ["missing.csv", "missing.csv.gz", "missing.mcap"])
def test_nonexistent_file(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    assert str(info.value) == f"{path}: cannot read file: No such file or directory"


def test_directory_and_unwritable_paths(tmp_path: Path) -> None:
    folder = tmp_path / "dir.csv"
    folder.mkdir()
    with pytest.raises(RecordingError, match="cannot read file: Is a directory"):
        read_csv(folder)
    for name in ["x.csv", "x.csv.gz", "x.mcap"]:
        with pytest.raises(RecordingError, match="cannot write file: No such file or directory"):
            write_recording(make_recording(10), tmp_path / "no" / "such" / name)


@pytest.mark.parametrize("name", ["run.txt", "run.json", "run.csv.bz2", "run"])
def test_unsupported_suffix(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_text("t,va\n0,1\n1,2\n")
    with pytest.raises(RecordingError, match=r"unsupported file type.*\.csv, \.csv\.gz or \.mcap"):
        read_recording(path)
    with pytest.raises(RecordingError, match="unsupported file type"):
        write_recording(make_recording(10), path)
