"""Tests of observer.recording: the Recording type and its CSV / MCAP formats."""

from __future__ import annotations

import gzip
import json
import logging
import math
import pickle
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from observer.recording import (
    CHANNELS,
    METADATA_NAME,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    UNITS,
    Recording,
    RecordingError,
    parse_sample_block,
    read_csv,
    read_mcap,
    read_recording,
    sample_block_message,
    validate_timebase,
    write_csv,
    write_mcap,
    write_recording,
)

RATE_HZ = 2000.0
PERIOD_NS = 500_000
METADATA = {"motor": {"field_resistance_ohm": 1.5, "name": "P-12"}, "seed": 7, "generator": "test"}


def make_recording(
    n: int = 2000,
    channels: Sequence[str] = CHANNELS,
    *,
    seed: int = 0,
    start_ns: int = 0,
    metadata: Mapping[str, Any] | None = None,
) -> Recording:
    """Sinusoids plus noise on a time base of whole nanoseconds (exact through MCAP)."""
    rng = np.random.default_rng(seed)
    t = (start_ns + np.arange(n, dtype=np.int64) * PERIOD_NS) / 1e9
    signals = {
        name: 10.0 * np.sin(2 * np.pi * (k + 1) * t + k) + 0.1 * rng.standard_normal(n)
        for k, name in enumerate(channels)
    }
    return Recording(
        t=t, signals=signals, metadata=dict(METADATA if metadata is None else metadata)
    )


def csv_text(rows: Sequence[Sequence[object]], header: str = "t,va,ia", comments: int = 1) -> str:
    """CSV text with ``comments`` comment lines: data row k (0-based) is on line comments+2+k."""
    lines = [f"# comment {i}" for i in range(comments)] + [header]
    lines += [",".join(str(cell) for cell in row) for row in rows]
    return "\n".join(lines) + "\n"


def good_rows(n: int = 10) -> list[list[object]]:
    return [[k * 0.001, 1.0 + k, -2.0 * k] for k in range(n)]


def write_raw_mcap(
    path: Path,
    blocks: Sequence[bytes],
    *,
    metadata: Mapping[str, str] | None = None,
    extra_topics: bool = False,
    finish: bool = True,
    chunk_size: int = 1024 * 1024,
    samples_encoding: str = "json",
) -> None:
    """An MCAP file holding the given /samples message payloads, optionally with other topics."""
    with path.open("wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        writer.start()
        schema_id = writer.register_schema(
            SAMPLES_SCHEMA_NAME, "jsonschema", json.dumps(SAMPLE_BLOCK_SCHEMA).encode()
        )
        samples = writer.register_channel(SAMPLES_TOPIC, samples_encoding, schema_id)
        if metadata is not None:
            writer.add_metadata(METADATA_NAME, dict(metadata))
        others: list[int] = []
        if extra_topics:
            other_schema = writer.register_schema("test.Estimate", "jsonschema", b"{}")
            others = [
                writer.register_channel("/estimates", "json", other_schema),
                writer.register_channel("/health", "json", other_schema),
            ]
            writer.add_metadata("other.tool", {"json": "not ours"})
        for k, data in enumerate(blocks):
            log_time = 1_000_000 * (k + 1)
            for channel in others:
                payload = json.dumps({"R": 1.5 + k, "t_ns": [1, 2, 3]}).encode()
                writer.add_message(channel, log_time, payload, log_time)
            writer.add_message(samples, log_time, data, log_time)
        if finish:
            writer.finish()


def block(t_ns: Sequence[int], **signals: Sequence[float]) -> bytes:
    return json.dumps({"t_ns": list(t_ns), **{k: list(v) for k, v in signals.items()}}).encode()


# --------------------------------------------------------------------------- Recording


def test_constants_are_consistent() -> None:
    assert CHANNELS == ("va", "ia", "vf", "if", "omega")
    assert set(UNITS) == {"t", *CHANNELS}
    assert set(SAMPLE_BLOCK_SCHEMA["properties"]) == {"t_ns", *CHANNELS}
    assert SAMPLE_BLOCK_SCHEMA["required"] == ["t_ns"]
    assert SAMPLE_BLOCK_SCHEMA["$schema"].endswith("2020-12/schema")
    json.dumps(SAMPLE_BLOCK_SCHEMA)  # serialisable as the MCAP schema record


def test_recording_stores_read_only_float64_copies() -> None:
    t = np.arange(10) * 0.5
    ia = np.arange(10)  # integers are accepted and converted
    rec = Recording(t=t, signals={"ia": ia})
    t[0] = 99.0
    ia[0] = 99
    assert rec.t[0] == 0.0 and rec["ia"][0] == 0.0
    assert rec.t.dtype == np.float64 and rec["ia"].dtype == np.float64
    assert not rec.t.flags.writeable and not rec["ia"].flags.writeable
    assert isinstance(rec.signals, MappingProxyType)
    with pytest.raises(TypeError):
        rec.signals["va"] = t  # type: ignore[index]
    with pytest.raises(ValueError):
        rec["ia"][1] = 5.0
    with pytest.raises(AttributeError):
        rec.t = t  # type: ignore[misc]


def test_recording_properties() -> None:
    rec = Recording(
        t=1.0 + np.arange(100) * 0.01, signals={"omega": np.ones(100), "va": np.zeros(100)}
    )
    assert rec.n_samples == 100
    assert rec.dt == pytest.approx(0.01)
    assert rec.sample_rate_hz == pytest.approx(100.0)
    assert rec.duration_s == pytest.approx(1.0)
    assert rec.channels == ("va", "omega")  # CHANNELS order, not insertion order
    assert list(rec.signals) == ["va", "omega"]
    assert "n_samples=100" in repr(rec)


def test_getitem_has_and_require() -> None:
    rec = make_recording(50, ("va", "ia"))
    assert rec["t"] is rec.t
    assert rec["va"] is rec.signals["va"]
    with pytest.raises(KeyError, match=r"no column 'vf'.*t, va, ia"):
        rec["vf"]
    assert rec.has("t", "va", "ia") and rec.has()
    assert not rec.has("va", "vf")
    rec.require("t", "va", "ia", purpose="the armature circuit")
    with pytest.raises(RecordingError) as info:
        rec.require("va", "vf", "if", path="run.csv", purpose="the field circuit")
    message = str(info.value)
    assert message.startswith("run.csv: column 'vf': missing columns 'vf', 'if'")
    assert "(needed for the field circuit)" in message
    assert "the recording has t, va, ia" in message
    assert info.value.column == "vf" and info.value.path == "run.csv"
    with pytest.raises(RecordingError, match=r"^column 'vf': missing column 'vf'; the recording"):
        rec.require("vf")
    with pytest.raises(ValueError, match="unknown column 'Vf'"):
        rec.require("Vf")


def test_slice_time_keeps_half_open_interval() -> None:
    rec = make_recording(100)
    part = rec.slice_time(rec.t[10], rec.t[20])
    assert part.n_samples == 10
    assert part.t[0] == rec.t[10] and part.t[-1] == rec.t[19]
    assert np.array_equal(part["ia"], rec["ia"][10:20])
    assert part.metadata == rec.metadata
    assert rec.slice_time(-1.0, 1e9) == rec
    with pytest.raises(RecordingError, match=r"holds 1 samples, fewer than 2"):
        rec.slice_time(rec.t[5], rec.t[6])
    with pytest.raises(RecordingError, match="holds 0 samples"):
        rec.slice_time(5.0, 1.0)


def test_select_channels() -> None:
    rec = make_recording(20)
    field = rec.select("if", "t", "vf")
    assert field.channels == ("vf", "if")
    assert np.array_equal(field["vf"], rec["vf"]) and field.metadata == rec.metadata
    with pytest.raises(KeyError, match="no channel 'vf'"):
        rec.select("va").select("vf")
    with pytest.raises(ValueError, match="at least one channel"):
        rec.select("t")


def test_metadata_is_normalised_through_json_and_read_only() -> None:
    rec = Recording(
        t=np.arange(3.0),
        signals={"va": np.zeros(3)},
        metadata={"gains": (1, 2), 3: "x"},  # type: ignore[dict-item]
    )
    assert dict(rec.metadata) == {"gains": [1, 2], "3": "x"}
    assert isinstance(rec.metadata, MappingProxyType)
    with pytest.raises(RecordingError, match="metadata is not JSON-serializable"):
        Recording(t=np.arange(3.0), signals={"va": np.zeros(3)}, metadata={"x": object()})
    with pytest.raises(RecordingError, match="metadata is not JSON-serializable"):
        Recording(t=np.arange(3.0), signals={"va": np.zeros(3)}, metadata={"x": math.nan})


def test_equality_and_pickling() -> None:
    rec = make_recording(30)
    assert rec == make_recording(30)
    assert rec != make_recording(30, seed=1)
    assert rec != make_recording(30, ("va", "ia", "vf", "if"))
    assert rec != make_recording(30, metadata={})
    assert pickle.loads(pickle.dumps(rec)) == rec
    error = RecordingError("value is NaN", path="x.csv", row=3, column="ia")
    copy = pickle.loads(pickle.dumps(error))
    assert str(copy) == str(error) and (copy.path, copy.row, copy.column) == ("x.csv", 3, "ia")


@pytest.mark.parametrize(
    ("t", "signals", "expected", "row", "column"),
    [
        ([0.0, 1.0], {"Va": [1.0, 2.0]}, "unknown channel 'Va'; allowed: va, ia", None, "Va"),
        ([0.0, 1.0], {}, "no signal channel", None, None),
        ([0.0, 1.0, 2.0], {"ia": [1.0, 2.0]}, "has 2 samples but t has 3", None, "ia"),
        ([0.0, 1.0, 2.0, 3.0], {"ia": [0.0, 1.0, 2.0, math.nan]}, "value is NaN", 4, "ia"),
        ([0.0, 1.0, math.inf], {"ia": [0.0, 1.0, 2.0]}, "value is inf", 3, "t"),
        ([0.0, 1.0, 1.0, 2.0], {"ia": [0.0] * 4}, "time not strictly increasing", 3, "t"),
        ([0.0, 1.0, 2.0, 3.5, 4.5], {"ia": [0.0] * 5}, "non-uniform sampling", 4, "t"),
        ([0.0], {"ia": [0.0]}, "fewer than 2 samples (found 1)", None, None),
        ([[0.0, 1.0]], {"ia": [0.0, 1.0]}, "must be 1-D", None, "t"),
        (["0", "1"], {"ia": [0.0, 1.0]}, "must hold numbers", None, "t"),
    ],
)
def test_recording_rejects_invalid_data(
    t: Any, signals: dict[str, Any], expected: str, row: int | None, column: str | None
) -> None:
    with pytest.raises(RecordingError) as info:
        Recording(t=np.asarray(t), signals=signals)
    assert expected in str(info.value)
    assert info.value.row == row and info.value.column == column
    assert info.value.path is None


def test_validate_timebase_reports_row_and_periods() -> None:
    t = np.arange(20) * 0.001
    validate_timebase(t)
    t[12:] += 0.0005  # one period of 1.5 ms
    with pytest.raises(RecordingError) as info:
        validate_timebase(t, path="run.csv", row_offset=2)
    message = str(info.value)
    assert message.startswith("run.csv: row 15, column 't': non-uniform sampling")
    assert "period 0.0015 s" in message and "expected 0.001 s" in message and "1%" in message
    validate_timebase(t, rel_tol=0.6)
    with pytest.raises(ValueError, match="rel_tol"):
        validate_timebase(t, rel_tol=0.0)


# --------------------------------------------------------------------------- CSV


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
        (lambda data: b"this is not gzip at all", "corrupt gzip file"),
        (lambda data: data[:40] + bytes([data[40] ^ 0xFF]) + data[41:], "corrupt gzip file"),
    ],
    ids=["cut-half", "cut-trailer", "not-gzip", "flipped-byte"],
)
def test_corrupt_gzip(tmp_path: Path, mangle: Any, expected: str) -> None:
    path = tmp_path / "run.csv.gz"
    write_csv(make_recording(500), path)
    path.write_bytes(mangle(path.read_bytes()))
    with pytest.raises(RecordingError) as info:
        read_csv(path)
    assert str(info.value).startswith(f"{path}: {expected}")
    assert "\n" not in str(info.value)


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


def test_csv_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(b"t,va\n0,1\n1,\xff\n")
    with pytest.raises(RecordingError, match=r"latin\.csv: not a UTF-8 text file \(byte 0xff"):
        read_csv(path)


@pytest.mark.parametrize("name", ["run.txt", "run.json", "run.csv.bz2", "run"])
def test_unsupported_suffix(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    path.write_text("t,va\n0,1\n1,2\n")
    with pytest.raises(RecordingError, match=r"unsupported file type.*\.csv, \.csv\.gz or \.mcap"):
        read_recording(path)
    with pytest.raises(RecordingError, match="unsupported file type"):
        write_recording(make_recording(10), path)


# --------------------------------------------------------------------------- MCAP messages


def test_sample_block_round_trip() -> None:
    t_ns = np.array([0, 500_000, 1_000_000], dtype=np.int64)
    signals = {"ia": np.array([0.1, 1 / 3, -2e-300]), "va": np.array([1, 2, 3])}
    data = sample_block_message(t_ns, signals)
    decoded = json.loads(data)
    assert list(decoded) == ["t_ns", "va", "ia"]  # CHANNELS order
    assert decoded["t_ns"] == [0, 500_000, 1_000_000]
    back_t, back = parse_sample_block(data)
    assert back_t.dtype == np.int64 and back_t.tolist() == t_ns.tolist()
    assert list(back) == ["va", "ia"]
    assert back["ia"].tolist() == [0.1, 1 / 3, -2e-300]
    assert back["va"].dtype == np.float64


@pytest.mark.parametrize(
    ("t_ns", "signals", "expected"),
    [
        ([0.0, 1.0], {"va": [1.0, 2.0]}, "integer nanoseconds"),
        ([], {"va": []}, "non-empty"),
        ([0, 1], {}, "at least one"),
        ([0, 1], {"Va": [1.0, 2.0]}, "unknown channel 'Va'"),
        ([0, 1], {"va": [1.0]}, "'va' has shape (1,)"),
        ([0, 1], {"va": [1.0, math.nan]}, "'va'[1] is nan"),
        ([0, 1], {"va": ["1", "2"]}, "must hold numbers"),
    ],
)
def test_sample_block_message_rejects(t_ns: Any, signals: Any, expected: str) -> None:
    with pytest.raises(ValueError) as info:
        sample_block_message(np.asarray(t_ns), signals)
    assert expected in str(info.value)


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (b"{not json", "not valid JSON"),
        (b"\xff\xfe", "not valid JSON"),
        (b"[1, 2]", "expected a JSON object, got list"),
        (b'{"va": [1.0]}', "missing field 't_ns'"),
        (b'{"t_ns": [1], "x": [1.0]}', "unknown field 'x'"),
        (b'{"t_ns": [1]}', "no signal field"),
        (b'{"t_ns": [1.5], "va": [1.0]}', "integer nanoseconds"),
        (b'{"t_ns": 1, "va": [1.0]}', "must be a JSON array"),
        (b'{"t_ns": [], "va": []}', "'t_ns' is empty"),
        (b'{"t_ns": [1], "va": ["1.0"]}', "must hold numbers"),
        (b'{"t_ns": [1], "va": [null]}', "must hold numbers"),
        (b'{"t_ns": [1, 2], "va": [[1.0], [2.0]]}', "flat array"),
        (b'{"t_ns": [1, 2], "va": [1.0, 2.0], "ia": [1.0]}', "unequal length"),
    ],
)
def test_parse_sample_block_rejects(data: bytes, expected: str) -> None:
    with pytest.raises(ValueError) as info:
        parse_sample_block(data)
    assert expected in str(info.value)


# --------------------------------------------------------------------------- MCAP files


def test_mcap_round_trip_is_exact(tmp_path: Path) -> None:
    rec = make_recording(3001, start_ns=123_000_000)
    path = tmp_path / "run.mcap"
    write_recording(rec, path, block_s=0.1)
    back = read_recording(path)
    assert back == rec
    assert dict(back.metadata) == METADATA

    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        assert {index.compression for index in summary.chunk_indexes} == {"zstd"}
        [schema] = summary.schemas.values()
        assert (schema.name, schema.encoding) == (SAMPLES_SCHEMA_NAME, "jsonschema")
        assert json.loads(schema.data) == SAMPLE_BLOCK_SCHEMA
        [channel] = summary.channels.values()
        assert (channel.topic, channel.message_encoding) == (SAMPLES_TOPIC, "json")
        messages = list(reader.iter_messages(topics=[SAMPLES_TOPIC]))
        [metadata] = list(reader.iter_metadata())
    assert metadata.name == METADATA_NAME and json.loads(metadata.metadata["json"]) == METADATA
    assert len(messages) == 16  # 200 samples per 0.1 s block, the last one partial
    for _schema, _channel, message in messages:
        t_ns, signals = parse_sample_block(message.data)
        assert message.log_time == message.publish_time == t_ns[0]
        assert list(signals) == list(CHANNELS)
    assert parse_sample_block(messages[-1][2].data)[0].size == 1


def test_mcap_time_round_trips_to_the_nanosecond(tmp_path: Path) -> None:
    t = 0.25 + np.arange(1000) / 3000.0  # not whole nanoseconds
    rec = Recording(t=t, signals={"va": np.cos(t)})
    path = tmp_path / "thirds.mcap"
    write_mcap(rec, path, block_s=0.05)
    back = read_mcap(path)
    assert np.abs(back.t - rec.t).max() <= 0.5e-9
    assert np.array_equal(back["va"], rec["va"])
    assert np.array_equal(back.t, np.rint(rec.t * 1e9) / 1e9)


def test_mcap_field_only_subset(tmp_path: Path) -> None:
    rec = make_recording(500, ("vf", "if"), metadata={})
    path = tmp_path / "field.mcap"
    write_mcap(rec, path)
    back = read_mcap(path)
    assert back == rec and back.channels == ("vf", "if") and dict(back.metadata) == {}


def test_mcap_write_rejects_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="block_s"):
        write_mcap(make_recording(10), tmp_path / "x.mcap", block_s=0.0)
    negative = Recording(t=np.arange(-5, 5) * 0.1, signals={"va": np.zeros(10)})
    with pytest.raises(RecordingError, match=r"x\.mcap: column 't': .*start at or after 0"):
        write_mcap(negative, tmp_path / "x.mcap")
    # Tiny blocks still hold at least one sample each.
    write_mcap(make_recording(10), tmp_path / "y.mcap", block_s=1e-9)
    assert read_mcap(tmp_path / "y.mcap") == make_recording(10)


def test_mcap_ignores_unrelated_topics_and_metadata(tmp_path: Path) -> None:
    rec = make_recording(400)
    blocks = [
        sample_block_message(
            np.rint(rec.t[i : i + 100] * 1e9).astype(np.int64),
            {c: rec[c][i : i + 100] for c in rec.channels},
        )
        for i in range(0, 400, 100)
    ]
    path = tmp_path / "daemon.mcap"
    meta = {"json": json.dumps(METADATA)}
    write_raw_mcap(path, blocks, metadata=meta, extra_topics=True)
    assert read_mcap(path) == rec


def test_mcap_cut_in_the_middle_gives_a_prefix(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    rec = make_recording(20000, seed=3)
    path = tmp_path / "full.mcap"
    write_mcap(rec, path)
    data = path.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    cut_path.write_bytes(data[: len(data) // 2])
    with caplog.at_level(logging.WARNING, logger="observer.recording"):
        part = read_mcap(cut_path)
    assert "unfinished or cut short" in caplog.text
    assert 2 <= part.n_samples < rec.n_samples
    assert part == Recording(
        t=rec.t[: part.n_samples],
        signals={c: v[: part.n_samples] for c, v in rec.signals.items()},
        metadata=rec.metadata,
    )


def test_mcap_any_cut_gives_a_prefix_or_a_clear_error(tmp_path: Path) -> None:
    rec = make_recording(6000, ("va", "ia"), seed=4)
    path = tmp_path / "full.mcap"
    write_mcap(rec, path)
    data = path.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    lengths: list[int] = []
    for cut in range(0, len(data), max(1, len(data) // 97)):
        cut_path.write_bytes(data[:cut])
        try:
            part = read_mcap(cut_path)
        except RecordingError as error:
            assert "\n" not in str(error)
            assert str(error).startswith(f"{cut_path}: ")
            assert any(
                text in str(error)
                for text in ("file is empty", "not an MCAP file", "no messages on topic")
            )
            continue
        n = part.n_samples
        assert np.array_equal(part.t, rec.t[:n]) and np.array_equal(part["ia"], rec["ia"][:n])
        assert part.metadata == rec.metadata
        lengths.append(n)
    assert lengths == sorted(lengths)
    # Cuts inside the data keep fewer samples; cuts in the summary section keep them all.
    assert lengths[0] < rec.n_samples and lengths[-1] == rec.n_samples


def test_mcap_never_finished(tmp_path: Path) -> None:
    rec = make_recording(4025, seed=5)
    blocks = [
        sample_block_message(
            np.rint(rec.t[i : i + 50] * 1e9).astype(np.int64),
            {c: rec[c][i : i + 50] for c in rec.channels},
        )
        for i in range(0, rec.n_samples, 50)
    ]
    path = tmp_path / "crashed.mcap"
    meta = {"json": json.dumps(METADATA)}
    write_raw_mcap(path, blocks, metadata=meta, extra_topics=True, finish=False, chunk_size=20_000)
    with path.open("rb") as stream, pytest.raises(McapError):
        list(make_reader(stream).iter_messages())  # the plain reader cannot open it
    part = read_mcap(path)
    assert 2 <= part.n_samples < rec.n_samples
    assert part.n_samples % 50 == 0  # whole messages only
    assert np.array_equal(part["omega"], rec["omega"][: part.n_samples])
    assert dict(part.metadata) == METADATA


def _located_mcap_error(path: Path) -> RecordingError:
    with pytest.raises(RecordingError) as info:
        read_mcap(path)
    assert "\n" not in str(info.value)
    assert str(info.value).startswith(f"{path}: ")
    return info.value


def test_mcap_unequal_lengths_in_a_block_names_the_message(tmp_path: Path) -> None:
    path = tmp_path / "unequal.mcap"
    blocks = [
        block([0, 1000], va=[1.0, 2.0], ia=[0.0, 0.0]),
        block([2000, 3000], va=[1.0, 2.0], ia=[0.0]),
    ]
    write_raw_mcap(path, blocks, extra_topics=True)
    error = _located_mcap_error(path)
    assert str(error) == (
        f"{path}: message 2 on '/samples' (log time 2000000 ns), column 'ia': "
        "malformed sample block: signals of unequal length: 'ia' has 1 samples but 't_ns' has 2"
    )
    assert (error.message_index, error.column, error.row) == (2, "ia", None)


@pytest.mark.parametrize(
    ("blocks", "expected", "message_index", "column"),
    [
        (
            [block([0, 1000], va=[1.0, 2.0]), b"{oops"],
            "message 2 on '/samples' (log time 2000000 ns): malformed sample block: not valid",
            2,
            None,
        ),
        (
            [block([0, 1000], va=[1.0, 2.0]), block([2000], va=[1.0], ia=[1.0])],
            "message 2 on '/samples' (log time 2000000 ns): channels va, ia differ from those "
            "of message 1 (va)",
            2,
            None,
        ),
        (
            [block([0, 1000], va=[1.0, 2.0]), block([2000, 3000], va=[1.0, math.nan])],
            "message 2 on '/samples' (log time 2000000 ns), sample 2, column 'va': value is NaN",
            2,
            "va",
        ),
        (
            [block([0, 1000], va=[1.0, 2.0]), block([1000, 2000], va=[1.0, 2.0])],
            "message 2 on '/samples' (log time 2000000 ns), sample 1, column 't': "
            "time not strictly increasing",
            2,
            "t",
        ),
        (
            [block([0, 1000, 2000], va=[0.0] * 3), block([3000, 4000, 6000], va=[0.0] * 3)],
            "message 2 on '/samples' (log time 2000000 ns), sample 3, column 't': "
            "non-uniform sampling: period 2e-06 s since the previous sample, expected 1e-06 s",
            2,
            "t",
        ),
        ([block([0], va=[1.0])], "fewer than 2 samples (found 1)", None, None),
        ([], "no messages on topic '/samples'", None, None),
    ],
    ids=[
        "bad-json",
        "channels-change",
        "nan",
        "not-increasing",
        "non-uniform",
        "one-sample",
        "no-samples",
    ],
)
def test_mcap_bad_content(
    tmp_path: Path,
    blocks: list[bytes],
    expected: str,
    message_index: int | None,
    column: str | None,
) -> None:
    path = tmp_path / "bad.mcap"
    write_raw_mcap(path, blocks, extra_topics=True)
    error = _located_mcap_error(path)
    assert expected in str(error)
    assert (error.message_index, error.column) == (message_index, column)


def test_mcap_wrong_encoding_and_bad_metadata(tmp_path: Path) -> None:
    good = [block([0, 1000], va=[1.0, 2.0])]
    path = tmp_path / "enc.mcap"
    write_raw_mcap(path, good, samples_encoding="cbor")
    assert "message encoding 'cbor', expected 'json'" in str(_located_mcap_error(path))
    write_raw_mcap(path, good, metadata={"json": "{broken"})
    assert "metadata record 'dcobserver.recording' is not valid JSON" in str(
        _located_mcap_error(path)
    )
    write_raw_mcap(path, good, metadata={"text": "{}"})
    assert "has no 'json' key" in str(_located_mcap_error(path))
    write_raw_mcap(path, good, metadata={"json": "[1]"})
    assert "must hold a JSON object" in str(_located_mcap_error(path))


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        (b"", "file is empty"),
        (b"t,va\n0,1\n1,2\n", "not an MCAP file"),
        (b"\x89MCA", "not an MCAP file"),
        (b"\x89MCAP0\r\n", "no messages on topic '/samples'"),
    ],
)
def test_mcap_not_a_recording(tmp_path: Path, content: bytes, expected: str) -> None:
    path = tmp_path / "odd.mcap"
    path.write_bytes(content)
    assert expected in str(_located_mcap_error(path))
