"""observer.recording.csv_format: CSV and gzip-compressed CSV recordings."""

from __future__ import annotations

import gzip
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from observer.recording import (
    Recording,
    RecordingError,
    read_csv,
    read_recording,
    write_csv,
    write_recording,
)
from tests.observer.recording.helpers import (
    METADATA,
    csv_text,
    good_rows,
    make_recording,
)


@pytest.mark.parametrize("name", ["run.csv", "run.csv.gz", "RUN.CSV"])
def test_csv_round_trip_is_exact(tmp_path: Path, name: str) -> None:
    rec = make_recording(3000)
    path = tmp_path / name
    write_recording(rec, path)
    back = read_recording(path)
    assert back == rec  # exact float64 equality of every array, and the metadata
    assert dict(back.metadata) == METADATA


def test_csv_gz_is_really_gzip_and_deterministic(tmp_path: Path) -> None:
    rec = make_recording(200)
    path = tmp_path / "a.csv.gz"
    write_csv(rec, path)
    first = path.read_bytes()
    write_csv(rec, path)  # no timestamp in the gzip header: same bytes every time
    assert first[:2] == b"\x1f\x8b"
    assert path.read_bytes() == first
    assert gzip.decompress(first).decode().splitlines()[1] == "t,va,ia,vf,if,omega"


def test_csv_written_layout(tmp_path: Path) -> None:
    rec = Recording(
        t=np.array([0.0, 0.1, 0.2]),
        signals={"if": np.array([1.0, 2.0, 1 / 3]), "vf": np.array([5.0, 5.0, 5.0])},
        metadata={"seed": 1},
    )
    path = tmp_path / "field.csv"
    write_csv(rec, path)
    assert path.read_text().splitlines() == [
        '# dcobserver-metadata: {"seed": 1}',
        "t,vf,if",
        "0.0,5.0,1.0",
        "0.1,5.0,2.0",
        f"0.2,5.0,{1 / 3!r}",
    ]
    write_csv(Recording(t=rec.t, signals=rec.signals), path)
    assert path.read_text().splitlines()[0] == "t,vf,if"  # no comment without metadata


def test_csv_field_only_file_in_any_column_order(tmp_path: Path) -> None:
    path = tmp_path / "field.csv"
    path.write_text("if,t,vf\n0.5,0.0,10.0\n0.6,0.01,10.5\n0.7,0.02,11.0\n")
    rec = read_csv(path)
    assert rec.channels == ("vf", "if")
    assert rec.t.tolist() == [0.0, 0.01, 0.02]
    assert rec["if"].tolist() == [0.5, 0.6, 0.7]
    assert rec["vf"].tolist() == [10.0, 10.5, 11.0]
    assert dict(rec.metadata) == {}
    rec.require("vf", "if", purpose="the field circuit")
    with pytest.raises(RecordingError, match="missing columns 'va', 'ia'"):
        rec.require("va", "ia", path=path, purpose="the armature circuit")


def test_csv_tolerates_comments_blank_lines_crlf_bom_and_spaces(tmp_path: Path) -> None:
    path = tmp_path / "excel.csv"
    text = "\ufeff# exported\r\n\r\n t , va \r\n0, 1.5\r\n\r\n0.5 ,2.5\r\n1,3.5\r\n\r\n"
    path.write_bytes(text.encode("utf-8"))
    rec = read_csv(path)
    assert rec.t.tolist() == [0.0, 0.5, 1.0]
    assert rec["va"].tolist() == [1.5, 2.5, 3.5]


def test_csv_rows_are_counted_as_file_lines_despite_blank_lines(tmp_path: Path) -> None:
    path = tmp_path / "gaps.csv"
    rows = [",".join(map(str, row)) for row in good_rows(6)]
    rows[4] = "0.004,nan,1"
    # line 1 comment, 2 header, 3-4 rows, 5 blank, 6-7 rows, 8 blank, 9 the NaN row
    path.write_text("# c\nt,va,ia\n" + "\n".join(rows[:2] + [""] + rows[2:4] + [""] + rows[4:]))
    with pytest.raises(RecordingError) as info:
        read_csv(path)
    assert str(info.value) == f"{path}: row 9, column 'va': value is NaN"


def test_csv_error_in_a_large_file_names_the_exact_row(tmp_path: Path) -> None:
    rec = make_recording(20000, ("va", "ia"))
    path = tmp_path / "big.csv"
    write_csv(rec, path)
    lines = path.read_text().splitlines()
    assert lines[1] == "t,va,ia"
    lines[19990] = lines[19990].split(",")[0] + ",-inf," + lines[19990].split(",")[2]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(RecordingError) as info:
        read_csv(path)
    assert info.value.row == 19991 and info.value.column == "va"
    assert str(info.value).endswith("row 19991, column 'va': value is -inf")


BAD_CSV_CASES = [
    pytest.param("", "file is empty", None, None, id="empty-file"),
    pytest.param("# only\n# comments\n\n", "no header row", None, None, id="only-comments"),
    pytest.param(csv_text(good_rows(), header="0,1,2"), "no header row", 2, None, id="no-header"),
    pytest.param(
        csv_text(good_rows(), header="time,va,ia"),
        "unknown column 'time'",
        2,
        "time",
        id="no-t-column-unknown-name",
    ),
    pytest.param(csv_text([[1, 2]] * 3, header="va,ia"), "no 't' column", 2, None, id="no-t"),
    pytest.param(csv_text([[0], [1]], header="t"), "no signal column", 2, None, id="no-signal"),
    pytest.param(
        csv_text(good_rows(), header="t,va,Ia"),
        "unknown column 'Ia' (did you mean 'ia'?); allowed: t, va, ia, vf, if, omega",
        2,
        "Ia",
        id="unknown-column",
    ),
    pytest.param(
        csv_text(good_rows(), header="t,ia,ia"),
        "duplicate column 'ia' (fields 2 and 3)",
        2,
        "ia",
        id="duplicate-column",
    ),
    pytest.param(
        csv_text(good_rows(), header="t,va,"),
        "empty column name in field 3",
        2,
        None,
        id="empty-column-name",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, 1.0], *good_rows(3)]),
        "expected 3 fields (t,va,ia), found 2",
        8,
        None,
        id="too-few-fields",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, 1.0, 2.0, 3.0]]),
        "found 4",
        8,
        None,
        id="too-many-fields",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, "1.0", "abc"]]),
        "non-numeric value 'abc'",
        8,
        "ia",
        id="non-numeric",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, '"1.0"', 2.0]]),
        "non-numeric value '\"1.0\"'",
        8,
        "va",
        id="quoted-number",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, "", 2.0]]), "empty cell", 8, "va", id="empty-cell"
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.005, "1_000", 2.0]]),
        "non-numeric value '1_000'",
        8,
        "va",
        id="digit-separator",
    ),
    pytest.param(csv_text([*good_rows(5), [0.005, 1.0, "nan"]]), "value is NaN", 8, "ia", id="nan"),
    pytest.param(csv_text([*good_rows(5), [0.005, "inf", 1.0]]), "value is inf", 8, "va", id="inf"),
    pytest.param(
        csv_text([*good_rows(5), ["-Infinity", 1.0, 1.0]]),
        "value is -inf",
        8,
        "t",
        id="minus-inf-time",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.004, 1.0, 1.0]]),
        "time not strictly increasing: t = 0.004 s follows t = 0.004 s",
        8,
        "t",
        id="repeated-time",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.001, 1.0, 1.0]]),
        "time not strictly increasing",
        8,
        "t",
        id="time-goes-back",
    ),
    pytest.param(
        csv_text([*good_rows(5), [0.0065, 1.0, 1.0], [0.0075, 1.0, 1.0]]),
        "non-uniform sampling: period 0.0025 s since the previous sample, "
        "expected 0.001 s (the median period) within 1%",
        8,
        "t",
        id="non-uniform",
    ),
    pytest.param(
        csv_text(good_rows(1)), "fewer than 2 samples (found 1)", None, None, id="one-sample"
    ),
    pytest.param(csv_text([]), "fewer than 2 samples (found 0)", None, None, id="header-only"),
    pytest.param(
        "# dcobserver-metadata: {not json\n" + csv_text(good_rows(), comments=0),
        "metadata comment is not valid JSON",
        1,
        None,
        id="bad-metadata",
    ),
    pytest.param(
        "# dcobserver-metadata: [1, 2]\n" + csv_text(good_rows(), comments=0),
        "metadata comment must hold a JSON object",
        1,
        None,
        id="metadata-not-object",
    ),
    pytest.param(
        '# dcobserver-metadata: {"a": NaN}\n' + csv_text(good_rows(), comments=0),
        "NaN is not valid JSON",
        1,
        None,
        id="metadata-nan",
    ),
]


@pytest.mark.parametrize("compressed", [False, True], ids=["csv", "gz"])
@pytest.mark.parametrize(("text", "expected", "row", "column"), BAD_CSV_CASES)
def test_csv_bad_input_gives_one_line_located_error(
    tmp_path: Path,
    compressed: bool,
    text: str,
    expected: str,
    row: int | None,
    column: str | None,
) -> None:
    path = tmp_path / ("bad.csv.gz" if compressed else "bad.csv")
    path.write_bytes(gzip.compress(text.encode()) if compressed else text.encode())
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    error = info.value
    message = str(error)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert expected in message
    assert (error.path, error.row, error.column) == (str(path), row, column)
    if row is not None:
        assert f"row {row}" in message
    if column is not None:
        assert f"column {column!r}" in message


def test_csv_example_message_shape(tmp_path: Path) -> None:
    path = tmp_path / "recording.csv"
    rows = good_rows(20)
    rows[14][2] = "NaN"
    path.write_text(csv_text(rows))
    with pytest.raises(RecordingError) as info:
        read_csv(path)
    assert str(info.value) == f"{path}: row 17, column 'ia': value is NaN"


@pytest.mark.parametrize(
    ("mangle", "expected"),
    [
        (lambda data: data[: len(data) // 2], "corrupt gzip file"),
        (lambda data: data[:-4], "corrupt gzip file"),
        (lambda data: b"this is not gzip at all", "not gzip-compressed (no gzip header)"),
        (lambda data: data[:40] + bytes([data[40] ^ 0xFF]) + data[41:], "corrupt gzip file"),
        # Decompresses to garbage rows before the CRC: still the file's fault, not a row's.
        (lambda data: data[:-300] + bytes([data[-300] ^ 0x10]) + data[-299:], "corrupt gzip"),
    ],
    ids=["cut-half", "cut-trailer", "not-gzip", "flipped-byte", "flipped-mid-stream"],
)
def test_corrupt_gzip(tmp_path: Path, mangle: Any, expected: str) -> None:
    path = tmp_path / "run.csv.gz"
    write_csv(make_recording(500), path)
    path.write_bytes(mangle(path.read_bytes()))
    with pytest.raises(RecordingError) as info:
        read_csv(path)
    assert str(info.value).startswith(f"{path}: {expected}")
    assert "\n" not in str(info.value)


def test_csv_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(b"t,va\n0,1\n1,\xff\n")
    with pytest.raises(RecordingError, match=r"latin\.csv: not a UTF-8 text file \(byte 0xff"):
        read_csv(path)
