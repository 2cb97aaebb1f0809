"""Recordings and raw CSV / MCAP files the recording tests build on."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import CompressionType, Writer

from observer.recording import (
    CHANNELS,
    METADATA_NAME,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    Recording,
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
