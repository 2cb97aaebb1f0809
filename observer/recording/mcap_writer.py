"""Writing MCAP recordings: ZSTD-compressed chunks of sample-block messages.

Samples are written as the compact protobuf blocks of
:mod:`~observer.recording.sample_proto` (ADC counts where the recording's
``"adc"`` metadata declares them), or, on request, as the older JSON blocks of
:mod:`~observer.recording.sample_block`, which every reader still reads.
"""

from __future__ import annotations

import json
import math
import os
from typing import Final

import numpy as np
from mcap.writer import CompressionType, Writer

from observer.recording.adc import adc_scales
from observer.recording.atomic import AtomicFile
from observer.recording.base import _TIME, PathArg, Recording, RecordingError
from observer.recording.sample_block import (
    METADATA_NAME,
    NS_PER_S,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    sample_block_message,
)
from observer.recording.sample_proto import PROTO_ENCODING, proto_schema_data, sample_block_proto

SAMPLE_ENCODINGS: Final = (PROTO_ENCODING, "json")
"""Encodings :func:`write_mcap` can write the samples in; the first is the default."""

# Small enough that a cut file loses little, large enough to compress well.
_MCAP_CHUNK_SIZE: Final = 256 * 1024


def write_mcap(
    rec: Recording, path: PathArg, *, block_s: float = 0.1, encoding: str = PROTO_ENCODING
) -> None:
    """Write a recording as MCAP.

    One message on :data:`SAMPLES_TOPIC` per block of ``block_s`` seconds
    (schema :data:`SAMPLES_SCHEMA_NAME`), log and publish time the block's
    first ``t_ns``; the metadata in a Metadata record :data:`METADATA_NAME` as
    ``{"json": ...}``; ZSTD-compressed chunks.

    Parameters
    ----------
    rec : Recording
        The recording; its times must be >= 0 (MCAP log times are unsigned).
    path : str or os.PathLike
        Destination; replaced only once the new file is complete
        (:mod:`observer.recording.atomic`).
    block_s : float
        Duration of the samples in one message (s); at least one sample per message.
    encoding : {"protobuf", "json"}
        ``protobuf``: the compact blocks, channels with ``"adc"`` metadata as
        counts; ``json``: the older JSON blocks (schema encoding ``jsonschema``).

    Raises
    ------
    RecordingError
        If the times cannot be stored or the file cannot be written.
    ValueError
        If ``block_s`` is not a positive finite number or ``encoding`` unknown.
    """
    if not (math.isfinite(block_s) and block_s > 0):
        raise ValueError(f"block_s must be a positive number of seconds, got {block_s!r}")
    if encoding not in SAMPLE_ENCODINGS:
        raise ValueError(f"encoding must be one of {SAMPLE_ENCODINGS}, got {encoding!r}")
    name = os.fspath(path)
    if rec.t[0] < 0 or rec.t[-1] * NS_PER_S >= 2.0**63:
        raise RecordingError(
            f"times {rec.t[0]:g} to {rec.t[-1]:g} s cannot be stored as MCAP log times "
            f"(unsigned 64-bit nanoseconds): shift t to start at or after 0",
            path=name,
            column=_TIME,
        )
    t_ns = np.rint(rec.t * NS_PER_S).astype(np.int64)
    if not (np.diff(t_ns) > 0).all():
        raise RecordingError(
            "sample period below 1 ns cannot be stored in MCAP", path=name, column=_TIME
        )
    per_block = max(1, round(block_s / rec.dt))
    try:
        scales = adc_scales(rec.metadata)
    except ValueError as exc:
        raise RecordingError(str(exc), path=name) from None
    try:
        with AtomicFile(name) as out:
            writer = Writer(
                out.stream, chunk_size=_MCAP_CHUNK_SIZE, compression=CompressionType.ZSTD
            )
            writer.start()
            if encoding == PROTO_ENCODING:
                schema_id = writer.register_schema(
                    name=SAMPLES_SCHEMA_NAME, encoding=PROTO_ENCODING, data=proto_schema_data()
                )
            else:
                schema_id = writer.register_schema(
                    name=SAMPLES_SCHEMA_NAME,
                    encoding="jsonschema",
                    data=json.dumps(SAMPLE_BLOCK_SCHEMA).encode("utf-8"),
                )
            channel_id = writer.register_channel(
                topic=SAMPLES_TOPIC, message_encoding=encoding, schema_id=schema_id
            )
            writer.add_metadata(METADATA_NAME, {"json": json.dumps(dict(rec.metadata))})
            for start in range(0, rec.n_samples, per_block):
                stop = start + per_block
                block_t_ns = t_ns[start:stop]
                block = {c: rec.signals[c][start:stop] for c in rec.channels}
                if encoding == PROTO_ENCODING:
                    data = sample_block_proto(block_t_ns, block, scales)
                else:
                    data = sample_block_message(block_t_ns, block)
                log_time = int(block_t_ns[0])
                writer.add_message(
                    channel_id=channel_id, log_time=log_time, data=data, publish_time=log_time
                )
            writer.finish()
    except OSError as exc:
        raise RecordingError(f"cannot write file: {exc.strerror or exc}", path=name) from exc
