"""observer.recording.sample_block: the sample-block message of MCAP files."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from observer.recording import (
    parse_sample_block,
    sample_block_message,
)


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
