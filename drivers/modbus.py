"""Modbus adapter: polls a drive's input/holding registers (pymodbus 3.16, TCP or RTU).

The register map (option ``registers``, a list of tables in the config file)
says where each channel lives: table (``input`` or ``holding``), address,
type (``int16``, ``uint16``, ``int32``, ``uint32``, ``float32``), word order
of 32-bit values (``big``: high word first, the common convention; or
``little``), and ``value_si = raw * scale + offset``. Two pseudo-channels make
the poll stream exact when the drive provides them:

``sequence``
    The drive's sample counter (uint16). A poll that sees the same counter as
    the previous one is a repeat (the drive has not updated yet) and is not a
    new sample (``repeated_polls``); a jump is counted as ``dropped`` samples
    (the poller was too slow to see them).
``time_us``
    The drive's microsecond clock (uint32): sample times are device time
    (see :class:`drivers.pump.DeviceClock`). Without it each sample is stamped
    with the host monotonic time at which the response arrived, and carries
    the poll's jitter (here 0.1-1 ms; more on a loaded host).

Each poll reads every table once, as one request spanning its mapped
addresses. Exception responses are counted (``exception_responses``, in
``errors``) and the poll skipped; a timeout (``timeouts``) or a lost connection
closes the connection (a late answer must not be taken for the next request's)
and the pump reconnects with exponential backoff. Neither is ever fatal.

Note the sample rate: at the 100-500 Hz a Modbus poll can reach, the armature
time constant of a typical motor (P-12: 5.7 ms) is not observable; the
observer then estimates the field, the resistances and K, and must hold La.
"""

from __future__ import annotations

import dataclasses
import logging
import struct
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import CHANNELS
from drivers.pump import DeviceClock, DeviceLost, PumpedSource, PumpOptions

log = logging.getLogger(__name__)

#: Register type -> (struct format, registers).
TYPES: dict[str, tuple[str, int]] = {
    "int16": ("h", 1),
    "uint16": ("H", 1),
    "int32": ("i", 2),
    "uint32": ("I", 2),
    "float32": ("f", 2),
}
PSEUDO_CHANNELS = ("sequence", "time_us")
TABLES = ("input", "holding")


@dataclass(frozen=True)
class RegisterSpec:
    """Where one channel lives in the drive's registers (one ``[[source.options.registers]]``)."""

    channel: str = dataclasses.field(
        default="", metadata={"choices": (*CHANNELS, *PSEUDO_CHANNELS)}
    )
    address: int = dataclasses.field(default=0, metadata={"min": 0, "max": 65535})
    type: str = dataclasses.field(default="int16", metadata={"choices": tuple(TYPES)})
    table: str = dataclasses.field(default="input", metadata={"choices": TABLES})
    scale: float = 1.0
    offset: float = 0.0
    word_order: str = dataclasses.field(
        default="", metadata={"choices": ("", "big", "little"), "help": "'' = the source's"}
    )

    def decode(self, words: list[int], default_order: str) -> float:
        """The SI value of this register's ``words`` (16-bit register values)."""
        fmt, n = TYPES[self.type]
        if n == 2 and (self.word_order or default_order) == "little":
            words = words[::-1]
        raw = struct.unpack(">" + fmt, struct.pack(">" + "H" * n, *words))[0]
        return float(raw) * self.scale + self.offset


def p12_register_map() -> list[RegisterSpec]:
    """The register map of ``dcobserver fake-drive modbus`` (float32, big word order)."""
    specs = [RegisterSpec("sequence", 0, "uint16"), RegisterSpec("time_us", 1, "uint32")]
    for k, channel in enumerate(CHANNELS):
        specs.append(RegisterSpec(channel, 3 + 2 * k, "float32"))
    return specs


@dataclass(frozen=True)
class ModbusOptions(PumpOptions):
    """``[source.options]`` of ``kind = "modbus"``."""

    transport: str = dataclasses.field(default="tcp", metadata={"choices": ("tcp", "rtu")})
    host: str = "127.0.0.1"
    port: int = dataclasses.field(default=502, metadata={"min": 1, "max": 65535})
    serial_port: str = dataclasses.field(
        default="/dev/ttyUSB0", metadata={"help": "RTU only; a device or a pyserial URL"}
    )
    baudrate: int = dataclasses.field(default=115200, metadata={"min": 1, "help": "RTU only"})
    device_id: int = dataclasses.field(default=1, metadata={"min": 0, "max": 255})
    poll_rate_hz: float = dataclasses.field(default=200.0, metadata={"min": 0.1, "max": 10000.0})
    timeout_s: float = dataclasses.field(default=0.1, metadata={"min": 0.001})
    word_order: str = dataclasses.field(default="big", metadata={"choices": ("big", "little")})
    registers: list[RegisterSpec] = dataclasses.field(default_factory=p12_register_map)

    def __post_init__(self) -> None:
        names = [r.channel for r in self.registers]
        if not any(n in CHANNELS for n in names):
            raise ValueError("registers: map at least one channel")
        if "" in names:
            raise ValueError("registers: every register needs a channel")
        if len(set(names)) != len(names):
            raise ValueError("registers: each channel at most once")
        for table in TABLES:
            regs = [r for r in self.registers if r.table == table]
            if regs:
                lo = min(r.address for r in regs)
                hi = max(r.address + TYPES[r.type][1] for r in regs)
                if hi - lo > 125:
                    raise ValueError(f"registers: the {table} registers span {hi - lo} > 125")


class ModbusSource(PumpedSource):
    """Samples polled from a drive's Modbus registers."""

    name = "modbus"
    Options = ModbusOptions
    counters = (
        *PumpedSource.counters, "polls", "timeouts", "exception_responses", "repeated_polls",
        "sequence_gaps", "late_polls",
    )  # fmt: skip

    def __init__(self, options: ModbusOptions | None = None, **overrides: Any) -> None:
        opts = options if options is not None else ModbusOptions()
        if overrides:
            opts = dataclasses.replace(opts, **overrides)
        super().__init__(**opts.pump_settings())
        self.options = opts
        self._period = 1.0 / opts.poll_rate_hz
        self._spans: list[tuple[str, int, int, list[RegisterSpec]]] = []
        for table in TABLES:
            regs = [r for r in opts.registers if r.table == table]
            if regs:
                lo = min(r.address for r in regs)
                hi = max(r.address + TYPES[r.type][1] for r in regs)
                self._spans.append((table, lo, hi - lo, regs))
        self._names = [c for c in CHANNELS if c in {r.channel for r in opts.registers}]
        self._has_seq = "sequence" in {r.channel for r in opts.registers}
        self._has_time = "time_us" in {r.channel for r in opts.registers}
        self._clock = DeviceClock(wrap=2**32, tick_ns=1000, max_step_ns=10**9)
        self._client: Any = None
        self._last_seq: int | None = None
        self._next_poll = 0.0

    def _connect(self) -> None:
        from pymodbus.client import ModbusSerialClient, ModbusTcpClient

        o = self.options
        if o.transport == "tcp":
            client: Any = ModbusTcpClient(o.host, port=o.port, timeout=o.timeout_s, retries=0)
            where = f"{o.host}:{o.port}"
        else:
            client = ModbusSerialClient(
                o.serial_port, baudrate=o.baudrate, timeout=o.timeout_s, retries=0
            )
            where = o.serial_port
        if not client.connect():
            client.close()
            raise DeviceLost(f"cannot connect to Modbus {o.transport} {where}")
        self._client = client
        self._last_seq = None
        self._clock.reset()
        self._next_poll = time.monotonic()

    def _disconnect(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            try:
                client.close()
            except Exception:  # closing a dead connection may fail; it is closed either way
                pass

    def _receive(self, timeout: float) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
        from pymodbus.exceptions import ConnectionException, ModbusIOException

        client = self._client
        if client is None:
            raise DeviceLost("Modbus client not connected")
        now = time.monotonic()
        wait = self._next_poll - now
        if wait > timeout:
            self._stop.wait(timeout)
            return None
        if wait > 0:
            self._stop.wait(wait)
        self._next_poll += self._period
        if self._next_poll < time.monotonic() - self._period:
            self._add(late_polls=1)  # fell behind (host busy): resume the schedule from now
            self._next_poll = time.monotonic() + self._period
        values: dict[str, float] = {}
        self._add(polls=1)
        for table, address, count, regs in self._spans:
            read = (
                client.read_input_registers if table == "input" else client.read_holding_registers
            )
            try:
                response = read(address, count=count, device_id=self.options.device_id)
            except ModbusIOException as exc:
                self._add(timeouts=1)
                raise DeviceLost(f"no response: {exc}") from exc
            except ConnectionException as exc:
                raise DeviceLost(f"connection lost: {exc}") from exc
            if response.isError():
                code = getattr(response, "exception_code", "?")
                self._add(exception_responses=1, errors=1)
                self._count(last_error=f"Modbus exception {code} reading {table} {address}")
                return None
            words = list(response.registers)
            for r in regs:
                n = TYPES[r.type][1]
                off = r.address - address
                values[r.channel] = r.decode(words[off : off + n], self.options.word_order)
        host_ns = time.monotonic_ns()
        if self._has_seq:
            seq = int(values["sequence"]) & 0xFFFF
            if self._last_seq is not None:
                step = (seq - self._last_seq) & 0xFFFF
                if step == 0:
                    self._add(repeated_polls=1)
                    return None
                if step > 1:
                    self._add(dropped=step - 1, sequence_gaps=1)
            self._last_seq = seq
        if self._has_time:
            t_ns = self._clock.convert(np.array([int(values["time_us"])]), host_ns)
        else:
            t_ns = np.array([host_ns], dtype=np.int64)
        return t_ns, {c: np.array([values[c]]) for c in self._names}
