"""CAN adapter: python-can bus (any interface), signals decoded from a DBC file by cantools.

The signal map (option ``signals``) names, for each channel, the DBC message
and signal that carry it (``"DriveArmature.ArmatureVoltage"``); cantools
applies the DBC's factor and offset, so values arrive in SI units. A sample
may span several frames: they are paired by a counter signal present in each
(option ``counter``, the signal name, e.g. ``"Counter"``), and a sample is
complete when every message of the map has arrived with the same counter.
``config/p12.dbc`` describes the fake drive's two frames per sample.

Health extras: ``frames`` (decoded), ``unknown_ids`` (frames whose ID the DBC
does not know: normal traffic of other nodes on a shared bus, skipped and not
an error), ``short_frames`` and ``undecodable`` (bad frames, counted in
``errors``), ``error_frames`` and ``remote_frames`` (skipped),
``incomplete_samples`` (a frame of a sample lost: the rest is
discarded), ``counter_gaps``; lost samples are counted in ``dropped``.

Timestamps: device time where the map names a time signal (``time``, a
microsecond counter of ``time_bits`` bits, see
:class:`drivers.pump.DeviceClock`); otherwise the host monotonic time at which
python-can received the sample's last frame.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.base import CHANNELS, SourceError
from drivers.pump import DeviceClock, DeviceLost, PumpedSource, PumpOptions

log = logging.getLogger(__name__)

#: The reader waits up to this long (s) to gather samples into one block.
BATCH_S = 0.01

#: The bundled DBC of the fake drive (config/p12.dbc in the source tree).
P12_DBC = Path(__file__).resolve().parent.parent / "config" / "p12.dbc"


def _p12_signals() -> dict[str, str]:
    return {
        "va": "DriveArmature.ArmatureVoltage",
        "ia": "DriveArmature.ArmatureCurrent",
        "vf": "DriveField.FieldVoltage",
        "if": "DriveField.FieldCurrent",
        "omega": "DriveField.Speed",
    }


@dataclass(frozen=True)
class CanOptions(PumpOptions):
    """``[source.options]`` of ``kind = "can"``."""

    interface: str = dataclasses.field(
        default="socketcan", metadata={"help": "python-can interface (socketcan, virtual, ...)"}
    )
    channel: str = dataclasses.field(default="can0", metadata={"help": "python-can channel"})
    bitrate: int = dataclasses.field(default=0, metadata={"min": 0, "help": "0: leave as is"})
    dbc: str = dataclasses.field(
        default=str(P12_DBC), metadata={"path": True, "help": "DBC file (relative: to the config)"}
    )
    signals: dict[str, str] = dataclasses.field(
        default_factory=_p12_signals, metadata={"help": "channel -> 'Message.Signal'"}
    )
    counter: str = dataclasses.field(
        default="Counter", metadata={"help": "signal pairing the frames of a sample; '' if none"}
    )
    counter_bits: int = dataclasses.field(default=8, metadata={"min": 1, "max": 32})
    time: str = dataclasses.field(
        default="DriveArmature.DeviceTime",
        metadata={"help": "'Message.Signal' of a microsecond device clock; '' for host time"},
    )
    time_bits: int = dataclasses.field(default=24, metadata={"min": 8, "max": 64})

    def __post_init__(self) -> None:
        if not self.signals:
            raise ValueError("signals: map at least one channel")
        for channel, where in {**self.signals, "time": self.time or "x.y"}.items():
            if channel != "time" and channel not in CHANNELS:
                raise ValueError(
                    f"signals: unknown channel {channel!r}; expected one of {CHANNELS}"
                )
            if where.count(".") != 1 or not all(where.split(".")):
                raise ValueError(f"{channel}: {where!r} is not 'Message.Signal'")


@dataclass
class _Decoder:
    """What one DBC message contributes to a sample."""

    message: Any  # cantools Message
    channels: list[tuple[str, str]]  # (channel, signal)
    time_signal: str | None


class CanSource(PumpedSource):
    """Samples from a CAN bus, decoded per a DBC file."""

    name = "can"
    Options = CanOptions
    counters = (
        *PumpedSource.counters, "frames", "unknown_ids", "short_frames", "undecodable",
        "incomplete_samples", "counter_gaps", "error_frames", "remote_frames",
    )  # fmt: skip

    def __init__(self, options: CanOptions | None = None, **overrides: Any) -> None:
        import cantools

        opts = options if options is not None else CanOptions()
        if overrides:
            opts = dataclasses.replace(opts, **overrides)
        super().__init__(**opts.pump_settings())
        self.options = opts
        try:
            db = cantools.database.load_file(str(opts.dbc))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as exc:
            raise SourceError(f"cannot load DBC {opts.dbc}: {exc}") from exc
        self._decoders: dict[int, _Decoder] = {}
        time_msg, _, time_sig = opts.time.partition(".")
        for channel, where in opts.signals.items():
            msg_name, _, sig_name = where.partition(".")
            msg = self._message(db, msg_name)
            if sig_name not in [s.name for s in msg.signals]:
                raise SourceError(f"DBC {opts.dbc}: message {msg_name} has no signal {sig_name!r}")
            dec = self._decoders.setdefault(msg.frame_id, _Decoder(msg, [], None))
            dec.channels.append((channel, sig_name))
        if opts.time:
            msg = self._message(db, time_msg)
            if msg.frame_id not in self._decoders:
                raise SourceError(f"time: message {time_msg} carries no mapped channel")
            self._decoders[msg.frame_id].time_signal = time_sig
        if opts.counter:
            for dec in self._decoders.values():
                if opts.counter not in [s.name for s in dec.message.signals]:
                    raise SourceError(
                        f"counter: message {dec.message.name} has no {opts.counter!r}"
                    )
        elif len(self._decoders) > 1:
            raise SourceError("counter: needed when the channels span several messages")
        self._names = [c for c in CHANNELS if c in opts.signals]
        self._counter_mod = 1 << opts.counter_bits
        self._clock = DeviceClock(wrap=1 << opts.time_bits, tick_ns=1000, max_step_ns=10**9)
        self._bus: Any = None
        self._pending: dict[int, dict[str, float]] = {}
        self._pending_frames: dict[int, set[int]] = {}
        self._last_counter: int | None = None

    @staticmethod
    def _message(db: Any, name: str) -> Any:
        try:
            return db.get_message_by_name(name)
        except KeyError:
            raise SourceError(f"DBC has no message {name!r}") from None

    def _connect(self) -> None:
        import can

        kwargs: dict[str, Any] = {}
        if self.options.bitrate:
            kwargs["bitrate"] = self.options.bitrate
        self._bus = can.Bus(
            interface=self.options.interface, channel=self.options.channel, **kwargs
        )
        self._pending.clear()
        self._pending_frames.clear()
        self._last_counter = None
        self._clock.reset()

    def _disconnect(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            try:
                bus.shutdown()
            except Exception:  # a bus that vanished may fail to shut down; it is gone
                pass

    def _receive(self, timeout: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        import can

        bus = self._bus
        if bus is None:
            raise DeviceLost("CAN bus not open")
        rows: list[list[float]] = []
        device_times: list[int] = []
        host_times: list[int] = []
        deadline = time.monotonic() + timeout
        batch_end: float | None = None
        wait = timeout
        counts = dict.fromkeys(
            (
                "frames",
                "unknown_ids",
                "short_frames",
                "undecodable",
                "error_frames",
                "remote_frames",
            ),
            0,
        )
        while True:
            try:
                msg = bus.recv(wait)
            except can.CanError as exc:
                raise DeviceLost(f"{self.options.interface} {self.options.channel}: {exc}") from exc
            if msg is None:
                break
            sample = self._take(msg, counts)
            if sample is not None:
                row, t_dev = sample
                rows.append(row)
                device_times.append(t_dev)
                host_times.append(time.monotonic_ns())
            if len(rows) >= 512:
                break
            if rows and batch_end is None:
                # Gather up to BATCH_S of samples per block: less CPU per sample.
                batch_end = min(deadline, time.monotonic() + BATCH_S)
            wait = max(0.0, (batch_end or deadline) - time.monotonic())
            if wait == 0.0:  # also ends a flood of frames that complete no sample
                break
        self._add(**{k: v for k, v in counts.items() if v})
        bad = counts["short_frames"] + counts["undecodable"]
        if bad:
            self._add(errors=bad)
            self._count(last_error="bad CAN frame")
        if not rows:
            return None
        values = np.array(rows, dtype=np.float64)
        if self.options.time:
            t_ns = self._clock.convert(np.array(device_times, dtype=np.int64), host_times[-1])
        else:
            t_ns = np.array(host_times, dtype=np.int64)
        return t_ns, {name: values[:, j].copy() for j, name in enumerate(self._names)}

    def _take(self, msg: Any, counts: dict[str, int]) -> tuple[list[float], int] | None:
        """Decode one frame; a sample's row and device time when it completes one."""
        if msg.is_error_frame or msg.is_remote_frame:
            counts["error_frames" if msg.is_error_frame else "remote_frames"] += 1
            return None
        dec = self._decoders.get(msg.arbitration_id)
        if dec is None:
            counts["unknown_ids"] += 1
            return None
        if len(msg.data) < dec.message.length:
            counts["short_frames"] += 1
            return None
        try:
            decoded = dec.message.decode(bytes(msg.data), decode_choices=False)
        except Exception:  # cantools raises several types on bad payloads
            counts["undecodable"] += 1
            return None
        counts["frames"] += 1
        key = int(decoded[self.options.counter]) if self.options.counter else 0
        values = self._pending.setdefault(key, {})
        frames = self._pending_frames.setdefault(key, set())
        for channel, signal in dec.channels:
            values[channel] = float(decoded[signal])
        if dec.time_signal is not None:
            values["__time"] = float(decoded[dec.time_signal])
        frames.add(msg.arbitration_id)
        if len(frames) < len(self._decoders):
            return None
        # Complete: older pending counters can no longer complete in order.
        del self._pending[key], self._pending_frames[key]
        stale = len(self._pending)
        if stale:
            self._add(incomplete_samples=stale)
            self._pending.clear()
            self._pending_frames.clear()
        if self.options.counter and self._last_counter is not None:
            gap = (key - self._last_counter - 1) % self._counter_mod
            if gap:
                self._add(dropped=gap, counter_gaps=1)
        self._last_counter = key
        t_dev = int(values.get("__time", 0))
        return [values[c] for c in self._names], t_dev
