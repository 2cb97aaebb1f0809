"""observer.recording.mcap_reader: other topics, cut and unfinished files, bad content."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
from mcap.exceptions import McapError
from mcap.reader import make_reader

from observer.recording import (
    Recording,
    RecordingError,
    read_mcap,
    sample_block_message,
    write_mcap,
)
from tests.observer.recording.helpers import (
    METADATA,
    block,
    make_recording,
    write_raw_mcap,
)


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


@pytest.mark.parametrize(("encoding", "n"), [("protobuf", 40000), ("json", 6000)])
def test_mcap_any_cut_gives_a_prefix_or_a_clear_error(
    tmp_path: Path, encoding: str, n: int
) -> None:
    rec = make_recording(n, ("va", "ia"), seed=4)  # more than one chunk
    path = tmp_path / "full.mcap"
    write_mcap(rec, path, encoding=encoding)
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
                for text in ("file is empty", "not an MCAP file", "nothing to read")
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
    error = str(_located_mcap_error(path))
    assert "message encoding 'cbor', expected 'protobuf' or 'json'" in error
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
        (b"\x89MCAP0\r\n", "cut short (or still being written) after 8 bytes"),
    ],
)
def test_mcap_not_a_recording(tmp_path: Path, content: bytes, expected: str) -> None:
    path = tmp_path / "odd.mcap"
    path.write_bytes(content)
    assert expected in str(_located_mcap_error(path))
