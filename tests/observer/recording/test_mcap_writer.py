"""observer.recording.mcap_writer: what is written reads back exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from observer.recording import (
    CHANNELS,
    METADATA_NAME,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    Recording,
    RecordingError,
    parse_sample_block,
    read_mcap,
    read_recording,
    write_mcap,
    write_recording,
)
from tests.observer.recording.helpers import (
    METADATA,
    make_recording,
)


def test_mcap_round_trip_is_exact(tmp_path: Path) -> None:
    rec = make_recording(3001, start_ns=123_000_000)
    path = tmp_path / "run.mcap"
    write_recording(rec, path, block_s=0.1)
    back = read_recording(path)
    assert back == rec
    assert dict(back.metadata) == METADATA

    with path.open("rb") as stream:  # the default: compact protobuf blocks
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        [schema] = reader.get_summary().schemas.values()
        assert (schema.name, schema.encoding) == (SAMPLES_SCHEMA_NAME, "protobuf")
        decoded = [m for _s, _c, _m, m in reader.iter_decoded_messages(topics=[SAMPLES_TOPIC])]
    assert len(decoded) == 16 and sum(m.n_samples for m in decoded) == 3001
    assert decoded[0].t0_ns == 123_000_000 and list(decoded[0].va.values) == list(rec["va"][:200])


def test_mcap_json_blocks_round_trip_exactly(tmp_path: Path) -> None:
    """The older encoding, which the bundled recordings still use."""
    rec = make_recording(3001, start_ns=123_000_000)
    path = tmp_path / "run.mcap"
    write_mcap(rec, path, block_s=0.1, encoding="json")
    back = read_recording(path)
    assert back == rec

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
