"""Serial ADC adapter: a binary frame stream over a UART (pyserial), e.g. 921600 baud.

Frame format (all multi-byte fields little-endian)::

    offset  size  field
    0       2     sync word 0xA5 0x5A
    2       1     n: number of channels (1..32)
    3       2     sequence counter, uint16, +1 per frame, wraps
    5       4     device timestamp, uint32 microseconds, wraps (~71.6 min)
    9       2*n   channel values, int16 raw ADC counts
    9+2n    2     CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection,
                  no final xor; check value 0x29B1 for b"123456789") of the
                  bytes from offset 2 to 8+2n (count, sequence, time, values)

A 5-channel frame is 21 bytes: 210 bit times with start/stop bits, so at
921600 baud the wire carries at most 4388 frames/s.

The parser (:class:`FrameParser`) is pure (no I/O): it is fed whatever bytes
arrived and returns the complete frames with a valid CRC. After garbage or a
torn frame it resynchronises on the next sync word; a candidate whose CRC
fails is counted and the search resumes one byte after its sync word, so a
good frame hidden inside a bad one is still found. The source counts CRC
failures as bad frames (``errors``) and sequence gaps as ``dropped`` samples
(a lost frame shows up as a gap at the next good frame).

Scaling: channel ``k`` of a frame is ``raw * scale[k] + offset[k]`` in SI
units and is named by ``channels[k]`` (an empty name ignores that channel).

Samples lost while the device is away are not counted: after a reconnect the
sequence counter starts afresh (the device may have restarted); the time gap
shows in the timestamps.

Timestamps: device time (the frame's microsecond counter, see
:class:`drivers.pump.DeviceClock`), anchored to host monotonic time at the
first frame of each connection.
"""

from __future__ import annotations

import binascii
import dataclasses
import logging
import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import CHANNELS, AdcScale
from drivers.pump import DeviceClock, DeviceLost, PumpedSource, PumpOptions

log = logging.getLogger(__name__)

SYNC = b"\xa5\x5a"
#: The reader waits up to this long (s) to gather frames into one block.
BATCH_S = 0.01
MAX_CHANNELS = 32
HEADER = struct.Struct("<BHI")  # n channels, sequence, device time (us)
#: Bytes of a frame besides the channel values: sync, header, CRC.
OVERHEAD = len(SYNC) + HEADER.size + 2


def crc16_ccitt_false(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (``binascii.crc_hqx`` with init 0xFFFF)."""
    return binascii.crc_hqx(data, 0xFFFF)


def frame_size(n_channels: int) -> int:
    """Bytes in a frame of ``n_channels`` channels."""
    return OVERHEAD + 2 * n_channels


def encode_frame(sequence: int, device_time_us: int, values: Any) -> bytes:
    """One frame: ``values`` are int16 raw counts; sequence and time wrap."""
    raw = np.asarray(values, dtype="<i2")
    if not 1 <= raw.shape[0] <= MAX_CHANNELS:
        raise ValueError(f"a frame carries 1..{MAX_CHANNELS} channels, got {raw.shape[0]}")
    body = HEADER.pack(raw.shape[0], sequence & 0xFFFF, device_time_us & 0xFFFFFFFF)
    body += raw.tobytes()
    return SYNC + body + crc16_ccitt_false(body).to_bytes(2, "little")


def encode_frames(sequence0: int, device_time_us: np.ndarray, raw: np.ndarray) -> bytes:
    """Consecutive frames of the rows of ``raw`` ((m, n) int16), sequence from ``sequence0``."""
    return b"".join(
        encode_frame(sequence0 + i, int(device_time_us[i]), raw[i]) for i in range(raw.shape[0])
    )


@dataclass(frozen=True)
class Frame:
    """One decoded frame."""

    sequence: int
    device_time_us: int
    values: tuple[int, ...]


class FrameParser:
    """Incremental, resynchronising parser of the frame stream. Never raises on input.

    Parameters
    ----------
    n_channels : int, optional
        If given, frames with another channel count are rejected as bad headers.

    Attributes
    ----------
    frames, crc_errors, bad_headers, skipped_bytes : int
        Good frames, CRC failures, sync words followed by an impossible channel
        count, and bytes discarded while searching for a sync word.
    """

    def __init__(self, n_channels: int | None = None) -> None:
        if n_channels is not None and not 1 <= n_channels <= MAX_CHANNELS:
            raise ValueError(f"n_channels must be in 1..{MAX_CHANNELS}, got {n_channels}")
        self.n_channels = n_channels
        self._buf = bytearray()
        self.frames = 0
        self.crc_errors = 0
        self.bad_headers = 0
        self.skipped_bytes = 0

    @property
    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Frames completed by ``data`` (possibly none), in stream order."""
        buf = self._buf
        buf += data
        out: list[Frame] = []
        pos = 0
        end = len(buf)
        while True:
            i = buf.find(SYNC, pos)
            if i < 0:
                # Keep a trailing first sync byte: the second may come next.
                keep = 1 if end > pos and buf[end - 1] == SYNC[0] else 0
                self.skipped_bytes += end - pos - keep
                pos = end - keep
                break
            self.skipped_bytes += i - pos
            pos = i
            if end - pos < 3:
                break
            n = buf[pos + 2]
            if n == 0 or n > MAX_CHANNELS or (self.n_channels and n != self.n_channels):
                self.bad_headers += 1
                pos += 1
                continue
            size = OVERHEAD + 2 * n
            if end - pos < size:
                break
            body = memoryview(buf)[pos + 2 : pos + size - 2]
            crc = buf[pos + size - 2] | (buf[pos + size - 1] << 8)
            if crc16_ccitt_false(body) != crc:
                body.release()
                self.crc_errors += 1
                pos += 1
                continue
            _, sequence, device_time = HEADER.unpack_from(body, 0)
            values = struct.unpack_from(f"<{n}h", body, HEADER.size)
            body.release()
            out.append(Frame(sequence, device_time, values))
            self.frames += 1
            pos += size
        del buf[:pos]
        return out


def _default_channels() -> list[str]:
    return list(CHANNELS)


def _default_scale() -> list[float]:
    # The fake drive's scaling for the P-12: see observer/commands/fake_drive.py.
    return list(SERIAL_P12_SCALE)


#: Raw count -> SI of the fake drive's P-12 frames: va, ia, vf, if, omega.
SERIAL_P12_SCALE: tuple[float, ...] = (0.01, 0.001, 0.02, 0.0001, 0.01)


@dataclass(frozen=True)
class SerialOptions(PumpOptions):
    """``[source.options]`` of ``kind = "serial"``."""

    port: str = dataclasses.field(
        default="/dev/ttyUSB0", metadata={"help": "serial device (or a symlink to it)"}
    )
    baudrate: int = dataclasses.field(default=921600, metadata={"min": 1})
    channels: list[str] = dataclasses.field(
        default_factory=_default_channels,
        metadata={"help": "channel name of each frame position; '' ignores that position"},
    )
    scale: list[float] = dataclasses.field(
        default_factory=_default_scale, metadata={"help": "SI units per raw count, per position"}
    )
    offset: list[float] = dataclasses.field(
        default_factory=list, metadata={"help": "SI offset per position (default 0)"}
    )

    def __post_init__(self) -> None:
        n = len(self.channels)
        if not 1 <= n <= MAX_CHANNELS:
            raise ValueError(f"channels: need 1..{MAX_CHANNELS} positions, got {n}")
        named = [c for c in self.channels if c]
        for c in named:
            if c not in CHANNELS:
                raise ValueError(f"channels: unknown channel {c!r}; expected one of {CHANNELS}")
        if len(set(named)) != len(named) or not named:
            raise ValueError("channels: each channel at most once, at least one named")
        if len(self.scale) != n:
            raise ValueError(f"scale: need {n} values (one per channel), got {len(self.scale)}")
        if self.offset and len(self.offset) != n:
            raise ValueError(f"offset: need {n} values (one per channel), got {len(self.offset)}")


class SerialAdcSource(PumpedSource):
    """Samples from a serial ADC streaming the frames of this module.

    Health extras: ``crc_errors``, ``bad_headers``, ``skipped_bytes``,
    ``sequence_gaps``, ``frames``, ``overrun_samples``.
    """

    name = "serial"
    Options = SerialOptions
    counters = (
        *PumpedSource.counters, "frames", "crc_errors", "bad_headers", "skipped_bytes",
        "sequence_gaps",
    )  # fmt: skip

    def __init__(self, options: SerialOptions | None = None, **overrides: Any) -> None:
        opts = options if options is not None else SerialOptions()
        if overrides:
            opts = dataclasses.replace(opts, **overrides)
        super().__init__(**opts.pump_settings())
        self.options = opts
        n = len(opts.channels)
        self._parser = FrameParser(n)
        # Bytes of 10 ms at the line rate (10 bits per byte on the wire).
        self._batch_bytes = max(frame_size(n), int(opts.baudrate / 10 * BATCH_S))
        self._index = [k for k, c in enumerate(opts.channels) if c]
        self._names = [opts.channels[k] for k in self._index]
        self._scale = np.array([opts.scale[k] for k in self._index])
        offset = opts.offset or [0.0] * n
        self._offset = np.array([offset[k] for k in self._index])
        # int16 counts: the log stores them, not float64 values (exact, a quarter the size).
        self.scales = {
            name: AdcScale(float(self._scale[j]), float(self._offset[j]), 16)
            for j, name in enumerate(self._names)
        }
        self._clock = DeviceClock(wrap=2**32, tick_ns=1000, max_step_ns=1_000_000_000)
        self._serial: Any = None
        self._next_seq: int | None = None
        self._counted = (0, 0, 0)

    def _connect(self) -> None:
        import serial

        self._serial = serial.Serial(self.options.port, self.options.baudrate, timeout=BATCH_S)
        # Bytes that waited in the port while nobody read are of unknown age and
        # would only start the stream with a gap: begin at the live edge.
        self._serial.reset_input_buffer()
        self._parser = FrameParser(len(self.options.channels))
        self._counted = (0, 0, 0)
        self._clock.reset()
        self._next_seq = None

    def _disconnect(self) -> None:
        ser, self._serial = self._serial, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # closing a vanished device may fail; it is gone either way
                pass

    def _receive(self, timeout: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        import serial

        ser = self._serial
        if ser is None:
            raise DeviceLost("serial port not open")
        try:
            # Gather up to BATCH_S of frames per call: far less CPU per sample than
            # waking for every frame, for at most BATCH_S of added latency.
            # (The timeout is set once at connect: setting it reconfigures the port.)
            data = ser.read(self._batch_bytes)
            waiting = ser.in_waiting
            if waiting:
                data += ser.read(waiting)
        except (serial.SerialException, OSError) as exc:
            raise DeviceLost(f"{self.options.port}: {exc}") from exc
        host_ns = time.monotonic_ns()
        if not data:
            return None
        frames = self._parser.feed(data)
        self._account()
        if not frames:
            return None
        seq = np.fromiter((f.sequence for f in frames), dtype=np.int64, count=len(frames))
        expected = np.empty_like(seq)
        expected[0] = seq[0] if self._next_seq is None else self._next_seq
        expected[1:] = (seq[:-1] + 1) & 0xFFFF
        gap = (seq - expected) & 0xFFFF
        self._next_seq = int((seq[-1] + 1) & 0xFFFF)
        if gap.any():
            self._add(dropped=int(gap.sum()), sequence_gaps=int(np.count_nonzero(gap)))
        times = np.fromiter((f.device_time_us for f in frames), dtype=np.int64, count=len(frames))
        t_ns = self._clock.convert(times, host_ns)
        raw = np.array([f.values for f in frames], dtype=np.float64)[:, self._index]
        si = self._offset + self._scale * raw  # AdcScale.values: the log recovers the counts
        self._add(frames=len(frames))
        return t_ns, {name: si[:, j].copy() for j, name in enumerate(self._names)}

    def _account(self) -> None:
        # Parser counters are per connection; health keeps running totals.
        p = self._parser
        now = (p.crc_errors, p.bad_headers, p.skipped_bytes)
        d_crc, d_bad, d_skip = (a - b for a, b in zip(now, self._counted, strict=True))
        self._counted = now
        if d_crc or d_bad or d_skip:
            self._add(errors=d_crc, crc_errors=d_crc, bad_headers=d_bad, skipped_bytes=d_skip)
            if d_crc:
                self._count(last_error="CRC error")
