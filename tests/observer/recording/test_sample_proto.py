"""observer.recording.sample_proto and .adc: compact blocks, ADC counts, exact round trips."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from observer.recording import (
    SAMPLES_TOPIC,
    AdcScale,
    Recording,
    adc_scales,
    parse_samples,
    quantise,
    read_mcap,
    sample_block_proto,
    write_mcap,
)
from tests.observer.recording.helpers import make_recording

FULL_SCALE = {"va": 20.0, "ia": 20.0, "vf": 20.0, "if": 20.0, "omega": 20.0}


def test_counts_of_is_exact_or_refuses() -> None:
    scale = AdcScale(lsb=0.1, offset=-3.0, bits=12)
    counts = np.arange(-2048, 2048)
    values = scale.values(counts)
    assert np.array_equal(scale.counts_of(values), counts)
    assert scale.counts_of(values + 1e-9) is None  # not a value this ADC can give
    assert scale.counts_of(np.array([np.nan])) is None
    assert AdcScale(lsb=1e-12).counts_of(np.array([1.0])) is None  # beyond 32-bit counts


def test_quantised_recording_is_stored_as_counts_and_reads_back_exactly(tmp_path: Path) -> None:
    rec = quantise(make_recording(4000), FULL_SCALE, bits=12)
    assert adc_scales(rec.metadata)["va"] == AdcScale(20.0 / 2048, 0.0, 12)
    counts_file, floats_file = tmp_path / "counts.mcap", tmp_path / "floats.mcap"
    json_file = tmp_path / "json.mcap"
    write_mcap(rec, counts_file)
    write_mcap(Recording(rec.t, rec.signals), floats_file)  # no "adc": float64 values
    write_mcap(rec, json_file, encoding="json")
    assert read_mcap(counts_file) == rec == read_mcap(json_file)
    # Noisy 2 kHz test data (~10 counts of noise): smaller than float64, far smaller than JSON.
    size = counts_file.stat().st_size
    assert size < 0.9 * floats_file.stat().st_size and size < 0.7 * json_file.stat().st_size
    with counts_file.open("rb") as stream:  # mcap's own reader with the protobuf decoder
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        first = next(m for *_, m in reader.iter_decoded_messages(topics=[SAMPLES_TOPIC]))
    assert len(first.va.values) == 0 and len(first.va.counts) == first.n_samples
    assert (first.va.lsb, first.va.bits) == (20.0 / 2048, 12)
    assert first.va.min <= first.va.mean <= first.va.max


def test_a_channel_that_is_not_quantised_falls_back_to_float64() -> None:
    rec = make_recording(100)
    scale = AdcScale(lsb=0.01)
    data = sample_block_proto(
        np.rint(rec.t * 1e9).astype(np.int64), dict(rec.signals), {"va": scale}
    )
    t_ns, signals, scales = parse_samples("protobuf", data)
    assert scales == {}  # va did not fit the scale: stored as float64, nothing rounded
    assert all(np.array_equal(signals[c], rec[c]) for c in rec.channels)


def test_irregular_times_round_trip_exactly() -> None:
    rng = np.random.default_rng(1)
    t_ns = 10**18 + np.cumsum(rng.integers(90_000, 110_000, 500))  # host-clock jitter
    values = rng.standard_normal(500)
    back_t, back, _ = parse_samples("protobuf", sample_block_proto(t_ns, {"ia": values}))
    assert np.array_equal(back_t, t_ns) and np.array_equal(back["ia"], values)
    single_t, single, _ = parse_samples("protobuf", sample_block_proto([7], {"if": [1.5]}))
    assert single_t.tolist() == [7] and single["if"].tolist() == [1.5]


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (b"\xff\xff\xff", "not a protobuf sample block"),
        (b"", "block holds no samples"),
    ],
)
def test_parse_rejects_malformed_messages(data: bytes, expected: str) -> None:
    with pytest.raises(ValueError, match=expected):
        parse_samples("protobuf", data)


def test_parse_rejects_inconsistent_blocks() -> None:
    good = sample_block_proto(np.arange(3), {"va": [1.0, 2.0, 3.0]}, {"va": AdcScale(1.0)})
    _, _, scales = parse_samples("protobuf", good)
    assert scales == {"va": AdcScale(1.0)}
    from observer.recording.sample_proto import _message_class

    message = _message_class().FromString(good)
    message.va.lsb = 0.0
    with pytest.raises(ValueError, match="lsb must be > 0"):
        parse_samples("protobuf", message.SerializeToString())
    message.va.lsb = 1.0
    message.va.counts.append(4)
    with pytest.raises(ValueError, match="'va' has 4 samples, expected 3"):
        parse_samples("protobuf", message.SerializeToString())


@pytest.mark.parametrize(
    ("adc", "expected"),
    [
        ([1, 2], "must be an object"),
        ({"x": {"lsb": 1.0}}, "unknown channel 'x'"),
        ({"va": {"offset": 1.0}}, "needs an object with 'lsb'"),
        ({"va": {"lsb": -1.0}}, "lsb must be > 0"),
        ({"va": {"lsb": 1.0, "bits": 1.5}}, "bits must be an integer"),
        ({"va": {"lsb": 1.0, "offset": "0"}}, "offset must be a number"),
    ],
)
def test_adc_metadata_is_validated(adc: Any, expected: str) -> None:
    with pytest.raises(ValueError, match=expected):
        adc_scales({"adc": adc})


def test_quantise_saturates_like_an_adc() -> None:
    rec = make_recording(2000, ("va",))
    q = quantise(rec, {"va": 5.0}, bits=4)  # 16 counts over +-5 V
    assert q["va"].max() == pytest.approx(5.0 - 5.0 / 8) and q["va"].min() == -5.0
    with pytest.raises(ValueError, match="not in the recording"):
        quantise(rec, {"ia": 1.0})
