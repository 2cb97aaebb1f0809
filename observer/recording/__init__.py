"""Recordings of DC-motor winding signals: the in-memory type and its files.

Start with :class:`Recording` (:mod:`observer.recording.base`), then
:func:`read_recording` / :func:`write_recording` below, which pick the format
by the file name: CSV (:mod:`~observer.recording.csv_format`) or MCAP
(:mod:`~observer.recording.mcap_reader`, :mod:`~observer.recording.mcap_writer`,
carrying the compact messages of :mod:`~observer.recording.sample_proto`, or
the older JSON ones of :mod:`~observer.recording.sample_block`). ADC counts and
their scales (the ``"adc"`` metadata): :mod:`~observer.recording.adc`; files in
other units are converted by :mod:`~observer.recording.units`. Every file
written (here and by the commands) appears whole or not at all:
:mod:`~observer.recording.atomic`.

Import rule: this package imports only ``observer.recording`` and
``observer.config`` (checked by ``tests/test_architecture.py``).
"""

from __future__ import annotations

import os

from observer.recording.adc import ADC_KEY, AdcScale, adc_scales, quantise
from observer.recording.atomic import (
    AtomicFile,
    atomic_open,
    check_writable,
    final_path,
    is_temporary,
)
from observer.recording.base import (
    CHANNELS,
    UNITS,
    PathArg,
    Recording,
    RecordingError,
    validate_timebase,
)
from observer.recording.csv_format import read_csv, write_csv
from observer.recording.mcap_reader import McapRecordStream, read_mcap
from observer.recording.mcap_writer import SAMPLE_ENCODINGS, write_mcap
from observer.recording.sample_block import (
    MEANINGS,
    METADATA_NAME,
    SAMPLE_BLOCK_SCHEMA,
    SAMPLES_SCHEMA_NAME,
    SAMPLES_TOPIC,
    parse_sample_block,
    sample_block_message,
)
from observer.recording.sample_proto import (
    PROTO_ENCODING,
    parse_samples,
    proto_schema_data,
    sample_block_proto,
)
from observer.recording.units import COLUMN_UNITS, parse_units, to_si

__all__ = [
    "ADC_KEY",
    "AtomicFile",
    "CHANNELS",
    "PROTO_ENCODING",
    "SAMPLE_ENCODINGS",
    "AdcScale",
    "COLUMN_UNITS",
    "MEANINGS",
    "METADATA_NAME",
    "SAMPLES_SCHEMA_NAME",
    "SAMPLES_TOPIC",
    "SAMPLE_BLOCK_SCHEMA",
    "UNITS",
    "McapRecordStream",
    "Recording",
    "RecordingError",
    "adc_scales",
    "atomic_open",
    "check_writable",
    "final_path",
    "is_temporary",
    "parse_sample_block",
    "parse_samples",
    "proto_schema_data",
    "quantise",
    "parse_units",
    "read_csv",
    "read_mcap",
    "read_recording",
    "sample_block_message",
    "sample_block_proto",
    "to_si",
    "validate_timebase",
    "write_csv",
    "write_mcap",
    "write_recording",
]


def _format_of(path: PathArg) -> str:
    # A file still being written (or cut by a crash) under its temporary name has the
    # format of its final name.
    lower = os.fspath(final_path(path)).lower()
    if lower.endswith((".csv", ".csv.gz")):
        return "csv"
    if lower.endswith(".mcap"):
        return "mcap"
    raise RecordingError(
        "unsupported file type: expected a name ending in .csv, .csv.gz or .mcap", path=path
    )


def read_recording(path: PathArg, *, notes: list[str] | None = None) -> Recording:
    """Read a recording, choosing the format by the file name.

    Parameters
    ----------
    path : str or os.PathLike
        A ``.csv``, ``.csv.gz`` or ``.mcap`` file.
    notes : list, optional
        Collects what a reader should know (an MCAP file cut short) instead of
        logging it as a warning.

    Raises
    ------
    RecordingError
        For any other suffix, or when the file is unreadable or invalid.
    """
    if _format_of(path) == "csv":
        return read_csv(path)
    return read_mcap(path, notes=notes)


def write_recording(rec: Recording, path: PathArg, *, block_s: float = 0.1) -> None:
    """Write a recording, choosing the format by the file name.

    Parameters
    ----------
    rec : Recording
        The recording.
    path : str or os.PathLike
        A ``.csv``, ``.csv.gz`` or ``.mcap`` file; replaced only once the new
        file is complete (:mod:`~observer.recording.atomic`).
    block_s : float
        MCAP only: duration of the samples in one message (s).

    Raises
    ------
    RecordingError
        For any other suffix, or when the file cannot be written.
    """
    if _format_of(path) == "csv":
        write_csv(rec, path)
    else:
        write_mcap(rec, path, block_s=block_s)
