"""The compact sample-block message: protobuf, with ADC counts where they are known.

One message per block of samples on :data:`~observer.recording.sample_block.SAMPLES_TOPIC`,
schema ``dcobserver.SampleBlock`` (encoding ``protobuf``; the descriptor is
built here, no ``protoc`` needed)::

    message Channel {                    // one channel of the block
      repeated double values = 1;        // SI values; empty when counts are stored
      repeated sint32 counts = 2;        // ADC counts: value = offset + lsb * count
      double lsb = 3;  double offset = 4;  uint32 bits = 5;
      double mean = 6; double min = 7; double max = 8;   // of the block, SI units
    }
    message SampleBlock {
      int64 t0_ns = 1;                   // data time (source clock) of the first sample
      int64 period_ns = 2;               // nominal sample period
      repeated sint64 t_residual_ns = 3; // t_ns[i] = t0_ns + i*period_ns + t_residual_ns[i];
                                         // empty: exactly uniform
      uint32 n_samples = 4;
      Channel va = 10; Channel ia = 11; Channel vf = 12; Channel if = 13; Channel omega = 14;
    }

Everything round-trips exactly: times as integers, values as float64 or as
counts whose values are checked to be the original float64 values
(:meth:`~observer.recording.adc.AdcScale.counts_of`). Foxglove decodes the
message from the schema in the file and plots any field: ``/samples.va.mean``
(and ``.min``, ``.max``) over time, ``/samples.va.values[:]`` or
``.counts[:]`` against the index for one block's waveform.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from google.protobuf import descriptor_pb2

from observer.recording.adc import AdcScale, scale_problem
from observer.recording.base import CHANNELS, UNITS, FloatArray, IntArray
from observer.recording.sample_block import (
    MEANINGS,
    SAMPLES_SCHEMA_NAME,
    _checked_block,
    _SampleBlockError,
    parse_sample_block,
)

PROTO_ENCODING: Final = "protobuf"
"""MCAP schema and message encoding of the compact sample blocks."""

_PROTO_FILE: Final = "dcobserver/sample_block.proto"
_FIRST_CHANNEL_FIELD: Final = 10


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    # protobuf is imported where it is needed: ~70 ms that commands not touching MCAP skip.
    from google.protobuf import descriptor_pb2

    field = descriptor_pb2.FieldDescriptorProto
    package, message = SAMPLES_SCHEMA_NAME.split(".")
    fd = descriptor_pb2.FileDescriptorProto(name=_PROTO_FILE, package=package, syntax="proto3")
    channel = fd.message_type.add(name="Channel")
    _add_fields(
        channel,
        ("values", 1, field.TYPE_DOUBLE, True),
        ("counts", 2, field.TYPE_SINT32, True),
        ("lsb", 3, field.TYPE_DOUBLE, False),
        ("offset", 4, field.TYPE_DOUBLE, False),
        ("bits", 5, field.TYPE_UINT32, False),
        ("mean", 6, field.TYPE_DOUBLE, False),
        ("min", 7, field.TYPE_DOUBLE, False),
        ("max", 8, field.TYPE_DOUBLE, False),
    )
    block = fd.message_type.add(name=message)
    _add_fields(
        block,
        ("t0_ns", 1, field.TYPE_INT64, False),
        ("period_ns", 2, field.TYPE_INT64, False),
        ("t_residual_ns", 3, field.TYPE_SINT64, True),
        ("n_samples", 4, field.TYPE_UINT32, False),
    )
    for index, name in enumerate(CHANNELS):
        block.field.add(
            name=name,
            number=_FIRST_CHANNEL_FIELD + index,
            type=field.TYPE_MESSAGE,
            type_name=f".{package}.Channel",
            label=field.LABEL_OPTIONAL,
        )
    # Comments travel with the schema: a reader a year from now sees the units.
    info = fd.source_code_info
    for index, name in enumerate(CHANNELS):
        location = info.location.add(path=[4, 1, 2, 4 + index])
        location.leading_comments = f" {MEANINGS[name].capitalize()} ({UNITS[name]}).\n"
    return fd


def _add_fields(message: Any, *fields: tuple[str, int, int, bool]) -> None:
    """Scalar fields ``(name, number, type, repeated)`` of a ``DescriptorProto``."""
    from google.protobuf import descriptor_pb2

    label = descriptor_pb2.FieldDescriptorProto
    for name, number, kind, repeated in fields:
        message.field.add(
            name=name,
            number=number,
            type=kind,
            label=label.LABEL_REPEATED if repeated else label.LABEL_OPTIONAL,
        )


@cache
def _message_class() -> Any:
    from google.protobuf import descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    pool.Add(_file_descriptor())
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(SAMPLES_SCHEMA_NAME))


def proto_schema_data() -> bytes:
    """The schema record's data: a serialized ``FileDescriptorSet`` of the message."""
    from google.protobuf import descriptor_pb2

    file_set = descriptor_pb2.FileDescriptorSet()
    file_set.file.append(_file_descriptor())
    return file_set.SerializeToString()


def sample_block_proto(
    t_ns: npt.ArrayLike,
    signals: Mapping[str, npt.ArrayLike],
    scales: Mapping[str, AdcScale] | None = None,
) -> bytes:
    """Encode one block of samples as the protobuf message.

    Parameters
    ----------
    t_ns : array_like of int
        Sample times, integer nanoseconds; non-empty, 1-D.
    signals : Mapping[str, array_like]
        Channels (a non-empty subset of :data:`CHANNELS`) to float arrays of
        the length of ``t_ns``.
    scales : Mapping[str, AdcScale], optional
        ADC scales of some channels: a channel whose values are all exactly
        ``scale.values(counts)`` is stored as counts, any other as float64.

    Returns
    -------
    bytes

    Raises
    ------
    ValueError
        On an empty block, unknown channels or arrays of unequal length.
    """
    times = _checked_block(t_ns, signals)
    times = times.astype(np.int64)
    n = times.size
    message = _message_class()()
    message.t0_ns = int(times[0])
    message.n_samples = n
    period = 0 if n < 2 else round((int(times[-1]) - int(times[0])) / (n - 1))
    message.period_ns = period
    residual = times - (times[0] + period * np.arange(n, dtype=np.int64))
    if residual.any():
        message.t_residual_ns.extend(residual.tolist())
    for name in CHANNELS:
        if name not in signals:
            continue
        values = np.asarray(signals[name], dtype=np.float64)
        if values.shape != times.shape:
            raise ValueError(f"{name!r} has shape {values.shape} but t_ns has {times.shape}")
        channel = getattr(message, name)
        scale = (scales or {}).get(name)
        counts = scale.counts_of(values) if scale is not None else None
        if scale is not None and counts is not None:
            channel.counts.extend(counts.tolist())
            channel.lsb, channel.offset, channel.bits = scale.lsb, scale.offset, scale.bits
        else:
            channel.values.extend(values.tolist())
        finite = values[np.isfinite(values)]
        if finite.size:
            channel.mean = float(finite.mean())
            channel.min = float(finite.min())
            channel.max = float(finite.max())
    data: bytes = message.SerializeToString()
    return data


def parse_sample_proto(data: bytes) -> tuple[IntArray, dict[str, FloatArray], dict[str, AdcScale]]:
    """Decode one protobuf sample block (inverse of :func:`sample_block_proto`).

    Returns
    -------
    t_ns : numpy.ndarray of int64
    signals : dict[str, numpy.ndarray of float64]
        The channels present, in :data:`CHANNELS` order.
    scales : dict[str, AdcScale]
        The scales of the channels stored as counts.

    Raises
    ------
    ValueError
        If the bytes are not such a message or its arrays disagree in length.
    """
    message = _message_class()()
    try:
        message.ParseFromString(data)
    except Exception as exc:  # protobuf's DecodeError and friends
        raise _SampleBlockError(f"not a protobuf sample block: {exc}") from None
    n = int(message.n_samples)
    if n == 0:
        raise _SampleBlockError("block holds no samples", "t_ns")
    residual = np.asarray(message.t_residual_ns, dtype=np.int64)
    if residual.size not in (0, n):
        raise _SampleBlockError(f"t_residual_ns has {residual.size} values, expected {n}", "t_ns")
    t_ns = message.t0_ns + message.period_ns * np.arange(n, dtype=np.int64)
    if residual.size:
        t_ns = t_ns + residual
    signals: dict[str, FloatArray] = {}
    scales: dict[str, AdcScale] = {}
    for name in CHANNELS:
        if not message.HasField(name):
            continue
        channel = getattr(message, name)
        if len(channel.counts):
            problem = scale_problem(channel.lsb, channel.offset, channel.bits)
            if problem:
                raise _SampleBlockError(problem, name)
            scale = AdcScale(channel.lsb, channel.offset, channel.bits)
            values = scale.values(np.asarray(channel.counts, dtype=np.int64))
            scales[name] = scale
        else:
            values = np.asarray(channel.values, dtype=np.float64)
        if values.size != n:
            raise _SampleBlockError(f"{name!r} has {values.size} samples, expected {n}", name)
        signals[name] = values
    if not signals:
        raise _SampleBlockError(f"a sample block needs at least one of {', '.join(CHANNELS)}")
    return t_ns, signals, scales


def parse_samples(
    message_encoding: str, data: bytes
) -> tuple[IntArray, dict[str, FloatArray], dict[str, AdcScale]]:
    """Decode a sample-block message of either encoding (``protobuf`` or the older ``json``).

    Raises
    ------
    ValueError
        On an unknown encoding or a malformed message.
    """
    if message_encoding == PROTO_ENCODING:
        return parse_sample_proto(data)
    if message_encoding == "json":
        t_ns, signals = parse_sample_block(data)
        return t_ns, signals, {}
    raise _SampleBlockError(
        f"message encoding {message_encoding!r}, expected {PROTO_ENCODING!r} or 'json'"
    )
