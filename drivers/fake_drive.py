"""Simulated drives speaking the adapters' real protocols (peers of ``dcobserver fake-drive``).

Each fake drive takes samples from an :class:`observer.simulation.drive_stream.DriveStream`
in real time (or ``speedup`` times faster; device timestamps stay in simulated
time) and serves them over a real transport: serial frames on a
pseudo-terminal, CAN frames per ``config/p12.dbc`` on a python-can bus, a
Modbus TCP server on 127.0.0.1. Protocol objects stay in ``drivers/``.

Fault injection (for tests and demos) is by explicit, deterministic periods:
``corrupt_every=N`` flips one bit in every N-th serial frame, and so on, so a
test knows exactly what the adapter should have counted.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drivers.serial_adc import SERIAL_P12_SCALE, encode_frame

log = logging.getLogger(__name__)


class Pacer:
    """How many samples are due at a rate of ``rate_hz * speedup`` since :meth:`start`."""

    def __init__(self, rate_hz: float, speedup: float = 1.0) -> None:
        if not rate_hz > 0 or not speedup > 0:
            raise ValueError(f"rate and speedup must be > 0, got {rate_hz}, {speedup}")
        self.rate = rate_hz * speedup
        self.sent = 0
        self._t0 = time.monotonic()

    def start(self) -> None:
        self._t0 = time.monotonic()
        self.sent = 0

    def due(self, max_n: int | None = None) -> int:
        """Samples due now (not yet taken); marks them taken."""
        n = int((time.monotonic() - self._t0) * self.rate) - self.sent
        if max_n is not None:
            n = min(n, max_n)
        n = max(n, 0)
        self.sent += n
        return n


def to_counts(values: np.ndarray, scale: tuple[float, ...] | np.ndarray) -> np.ndarray:
    """SI values -> int16 ADC counts (rounded, saturating like an ADC)."""
    counts = np.rint(np.asarray(values) / np.asarray(scale))
    return np.clip(counts, -32768, 32767).astype(np.int16)


@dataclass
class FaultPlan:
    """Deterministic faults of a serial fake drive (0 disables each).

    Attributes
    ----------
    corrupt_every : int
        Flip one bit in every N-th frame (the CRC then fails).
    garbage_every : int
        Insert 1..64 random bytes before every N-th frame.
    tear_every : int
        Cut every N-th frame short (the rest of it is never sent).
    """

    corrupt_every: int = 0
    garbage_every: int = 0
    tear_every: int = 0


class SerialFakeDrive:
    """Serial ADC frames of a simulated drive on a pseudo-terminal.

    The pseudo-terminal's slave side is the "device": open :attr:`device_path`
    (or ``link``, a symlink to it that survives restarts of the fake drive)
    with pyserial. Writes are non-blocking: when nobody reads and the
    terminal's buffer is full, frames are discarded (``unsent_frames``) as a
    real UART transmits into the void; their sequence numbers are consumed,
    so the adapter sees the loss as a sequence gap.
    """

    def __init__(
        self,
        stream: Any,
        *,
        speedup: float = 1.0,
        link: str | os.PathLike[str] | None = None,
        faults: FaultPlan | None = None,
        seed: int = 0,
        scale: tuple[float, ...] = SERIAL_P12_SCALE,
    ) -> None:
        self.stream = stream
        self.pacer = Pacer(stream.sample_rate_hz, speedup)
        self.faults = faults or FaultPlan()
        self.scale = np.asarray(scale)
        self._rng = np.random.default_rng(seed)
        if link is not None and Path(link).exists() and not Path(link).is_symlink():
            raise FileExistsError(f"{link} exists and is not a symlink; not replacing it")
        self.master_fd, self._slave_fd = os.openpty()
        # Raw mode at once: a cooked terminal would translate CR/LF and echo.
        tty.setraw(self._slave_fd)
        tty.setraw(self.master_fd)
        os.set_blocking(self.master_fd, False)
        self.device_path = os.ttyname(self._slave_fd)
        self.link = Path(link) if link is not None else None
        if self.link is not None:
            tmp = self.link.with_name(self.link.name + ".tmp")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(self.device_path)
            os.replace(tmp, self.link)
        self.frames_sent = 0
        self.unsent_frames = 0
        self.faults_injected = 0
        self._pending = b""
        self._stop = threading.Event()

    def _frame_bytes(self, seq: int, t_us: int, counts: np.ndarray) -> bytes:
        frame = encode_frame(seq, t_us, counts)
        f = self.faults
        k = seq + 1
        if f.corrupt_every and k % f.corrupt_every == 0:
            b = bytearray(frame)
            pos = int(self._rng.integers(2, len(b)))  # not the sync word: a pure CRC failure
            b[pos] ^= 1 << int(self._rng.integers(0, 8))
            frame = bytes(b)
            self.faults_injected += 1
        if f.tear_every and k % f.tear_every == 0:
            frame = frame[: int(self._rng.integers(1, len(frame)))]
            self.faults_injected += 1
        if f.garbage_every and k % f.garbage_every == 0:
            n = int(self._rng.integers(1, 65))
            frame = self._rng.integers(0, 256, n, dtype=np.uint8).tobytes() + frame
            self.faults_injected += 1
        return frame

    def step(self) -> int:
        """Send the frames due now; returns how many were generated."""
        n = self.pacer.due(max_n=4096)
        if n == 0:
            return 0
        first = self.stream.index
        samples = self.stream.take(n)
        counts = to_counts(samples, self.scale)
        dt_us = 1e6 / self.stream.sample_rate_hz
        chunks = []
        for i in range(n):
            k = first + i
            chunks.append(self._frame_bytes(k & 0xFFFF, int(round(k * dt_us)), counts[i]))
        self._write(chunks)
        return n

    def _write(self, frames: list[bytes]) -> None:
        if self._pending:
            self._pending = self._pending[self._try_write(self._pending) :]
        for i, frame in enumerate(frames):
            if self._pending:
                # The terminal is full: a real UART would be sending these into the void.
                self.unsent_frames += len(frames) - i
                return
            written = self._try_write(frame)
            if written < len(frame):
                self._pending = frame[written:]
            self.frames_sent += 1

    def _try_write(self, data: bytes) -> int:
        try:
            return os.write(self.master_fd, data)
        except BlockingIOError:
            return 0

    def run(self, stop: threading.Event | None = None, duration_s: float | None = None) -> None:
        """Serve until ``stop`` is set or ``duration_s`` of simulated time has been sent."""
        stop = stop or self._stop
        self.stream.prefetch()
        self.pacer.start()
        limit = None if duration_s is None else int(duration_s * self.stream.sample_rate_hz)
        while not stop.is_set():
            self.step()
            if limit is not None and self.stream.index >= limit:
                break
            stop.wait(0.002)

    def close(self) -> None:
        """Close both ends of the terminal (a reader then sees the device vanish)."""
        self._stop.set()
        link = getattr(self, "link", None)
        if link is not None and link.is_symlink() and os.readlink(link) == self.device_path:
            link.unlink()  # only our own link: a newer fake drive may have taken it over
        for fd in (self.master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass


class CanFakeDrive:
    """CAN frames of a simulated drive per a DBC (default ``config/p12.dbc``) on a python-can bus.

    Each sample is sent as the frames of the signal map of :class:`drivers.can_bus.CanOptions`
    (for the P-12 DBC: ``DriveArmature`` then ``DriveField``), with a sample
    counter and a microsecond device clock. Values beyond a signal's DBC range
    saturate at its limit, as the drive's fixed-point encoding would.
    """

    def __init__(
        self,
        stream: Any,
        bus: Any,
        *,
        speedup: float = 1.0,
        dbc: str | os.PathLike[str] | None = None,
        counter: str = "Counter",
        time_signal: str = "DriveArmature.DeviceTime",
        counter_bits: int = 8,
        time_bits: int = 24,
    ) -> None:
        import can
        import cantools

        from drivers.can_bus import P12_DBC, _p12_signals

        self._can = can
        self.stream = stream
        self.bus = bus
        self.pacer = Pacer(stream.sample_rate_hz, speedup)
        db: Any = cantools.database.load_file(str(dbc or P12_DBC))
        columns = {name: i for i, name in enumerate(("va", "ia", "vf", "if", "omega"))}
        by_message: dict[str, list[tuple[str, int]]] = {}
        for channel, where in _p12_signals().items():
            msg_name, _, sig = where.partition(".")
            by_message.setdefault(msg_name, []).append((sig, columns[channel]))
        self._plan = []
        for msg_name, sigs in by_message.items():
            msg = db.get_message_by_name(msg_name)
            limits = {s.name: (s.minimum, s.maximum) for s in msg.signals}
            self._plan.append((msg, sigs, limits))
        self._time_msg, _, self._time_sig = time_signal.partition(".")
        self.counter = counter
        self._counter_mod = 1 << counter_bits
        self._time_mod = 1 << time_bits
        self.frames_sent = 0

    def frames_of(self, k: int, sample: np.ndarray) -> list[Any]:
        """The CAN messages of sample number ``k``."""
        t_us = int(round(k * 1e6 / self.stream.sample_rate_hz)) % self._time_mod
        out = []
        for msg, sigs, limits in self._plan:
            values: dict[str, float] = {}
            for sig, col in sigs:
                lo, hi = limits[sig]
                values[sig] = float(min(max(sample[col], lo), hi))
            values[self.counter] = k % self._counter_mod
            if msg.name == self._time_msg:
                values[self._time_sig] = t_us
            data = msg.encode(values)
            out.append(
                self._can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False)
            )
        return out

    def step(self) -> int:
        """Send the samples due now; returns how many."""
        n = self.pacer.due(max_n=4096)
        if n == 0:
            return 0
        first = self.stream.index
        samples = self.stream.take(n)
        for i in range(n):
            for message in self.frames_of(first + i, samples[i]):
                self.bus.send(message)
                self.frames_sent += 1
        return n

    def run(self, stop: threading.Event, duration_s: float | None = None) -> None:
        """Serve until ``stop`` is set or ``duration_s`` of simulated time was sent."""
        self.stream.prefetch()
        self.pacer.start()
        limit = None if duration_s is None else int(duration_s * self.stream.sample_rate_hz)
        while not stop.is_set():
            self.step()
            if limit is not None and self.stream.index >= limit:
                break
            stop.wait(0.002)


#: Extra registers of the Modbus fake drive, to exercise the other types of a
#: register map: int16 copies (address 20..24, scales as the serial ADC's) and
#: the speed as int32 in units of 1e-4 rad/s, low word first (30..31).
MODBUS_INT16_BASE = 20
MODBUS_OMEGA_INT32 = 30


class ModbusFakeDrive:
    """A Modbus TCP server (pymodbus) whose registers hold the simulated drive's latest sample.

    Register map (input and holding registers share memory), 32-bit values
    high word first unless noted::

        0       sample counter, uint16
        1-2     device time, uint32 microseconds
        3-12    va, ia, vf, if, omega as float32 (V, A, V, A, rad/s)
        20-24   va, ia, vf, if, omega as int16 counts (x0.01 V, x0.001 A,
                x0.02 V, x0.0001 A, x0.01 rad/s)
        30-31   omega as int32, 1e-4 rad/s, LOW word first

    The registers are filled at each request with the sample due at that
    moment (the drive's own sample clock runs at ``sample_rate_hz *
    speedup``). ``framer="rtu"`` speaks RTU frames (with CRC) over the TCP
    connection, as a serial-to-Ethernet gateway would pass them through: an
    RTU client reaches it with the pyserial URL ``socket://host:port``.
    Faults: every ``exception_every``-th request is answered with exception 6
    (device busy); every ``stall_every``-th is answered only after ``stall_s``
    seconds (a client times out).
    """

    def __init__(
        self,
        stream: Any,
        *,
        speedup: float = 1.0,
        device_id: int = 1,
        exception_every: int = 0,
        stall_every: int = 0,
        stall_s: float = 0.5,
        framer: str = "socket",
    ) -> None:
        self.stream = stream
        self.framer = framer
        self.pacer = Pacer(stream.sample_rate_hz, speedup)
        self.device_id = device_id
        self.exception_every = exception_every
        self.stall_every = stall_every
        self.stall_s = stall_s
        self.requests = 0
        self._latest = np.zeros(5)
        self._server: Any = None

    def _advance(self) -> int:
        n = self.pacer.due()
        if n:
            self._latest = self.stream.take(n)[-1]
        return self.stream.index - 1

    def fill(self, registers: list[int], start: int) -> None:
        """Write the current sample into ``registers`` (the device memory from ``start``)."""
        import struct

        k = max(self._advance(), 0)
        t_us = int(round(k * 1e6 / self.stream.sample_rate_hz)) & 0xFFFFFFFF
        words: dict[int, int] = {0: k & 0xFFFF, 1: t_us >> 16, 2: t_us & 0xFFFF}
        for c, value in enumerate(self._latest):
            hi, lo = struct.unpack(">HH", struct.pack(">f", float(value)))
            words[3 + 2 * c], words[4 + 2 * c] = hi, lo
        counts = to_counts(self._latest, SERIAL_P12_SCALE)
        for c in range(5):
            words[MODBUS_INT16_BASE + c] = int(counts[c]) & 0xFFFF
        omega = int(np.clip(np.rint(self._latest[4] * 1e4), -(2**31), 2**31 - 1))
        hi, lo = struct.unpack(">HH", struct.pack(">i", omega))
        words[MODBUS_OMEGA_INT32], words[MODBUS_OMEGA_INT32 + 1] = lo, hi
        for address, word in words.items():
            registers[address - start] = word

    async def _action(
        self,
        function_code: int,
        start_address: int,
        address: int,
        count: int,
        registers: list[int],
        set_values: Any,
    ) -> Any:
        import asyncio

        from pymodbus.constants import ExcCodes

        self.requests += 1
        if self.exception_every and self.requests % self.exception_every == 0:
            return ExcCodes.DEVICE_BUSY
        if self.stall_every and self.requests % self.stall_every == 0:
            await asyncio.sleep(self.stall_s)
        self.fill(registers, start_address)
        return None

    async def start(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start serving; returns the bound ``(host, port)``."""
        from pymodbus import FramerType
        from pymodbus.server import ModbusTcpServer
        from pymodbus.simulator import DataType, SimData, SimDevice

        self.stream.prefetch()
        device = SimDevice(
            id=self.device_id,
            simdata=[SimData(address=0, count=40, values=0, datatype=DataType.REGISTERS)],
            action=self._action,
        )
        framer = FramerType.RTU if self.framer == "rtu" else FramerType.SOCKET
        self._server = ModbusTcpServer(device, address=(host, port), framer=framer)
        await self._server.serve_forever(background=True)
        self.pacer.start()
        self._latest = self.stream.take(1)[0]  # sample k is then current from k / rate
        sock = self._server.transport.sockets[0]
        bound: tuple[str, int] = sock.getsockname()[:2]
        return bound

    async def stop(self) -> None:
        if self._server is not None:
            await self._server.shutdown()
            self._server = None
