"""Recordings of DC-motor winding signals: the in-memory type and its files.

Start with :class:`Recording` (:mod:`observer.recording.base`) and
:func:`read_recording` / :func:`write_recording` below, which pick the format
by the file name.

Import rule: this package imports only ``observer.recording`` and
``observer.config`` (checked by ``tests/test_architecture.py``).
"""

from observer.recording.base import (
    CHANNELS,
    METADATA_NAME,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    UNITS,
    McapRecordStream,
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

__all__ = [
    "CHANNELS",
    "METADATA_NAME",
    "SAMPLES_SCHEMA_NAME",
    "SAMPLES_TOPIC",
    "SAMPLE_BLOCK_SCHEMA",
    "UNITS",
    "McapRecordStream",
    "Recording",
    "RecordingError",
    "parse_sample_block",
    "read_csv",
    "read_mcap",
    "read_recording",
    "sample_block_message",
    "validate_timebase",
    "write_csv",
    "write_mcap",
    "write_recording",
]
