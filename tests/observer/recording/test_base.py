"""observer.recording.base: the Recording type, its validation and its errors."""

from __future__ import annotations

import json
import math
import pickle
from types import MappingProxyType
from typing import Any

import numpy as np
import pytest

from observer.recording import (
    CHANNELS,
    SAMPLE_BLOCK_SCHEMA,
    UNITS,
    Recording,
    RecordingError,
    validate_timebase,
)
from tests.observer.recording.helpers import (
    make_recording,
)


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
