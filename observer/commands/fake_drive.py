"""``dcobserver fake-drive can|serial|modbus``: a simulated drive on a real transport.

Runs the motor simulator in real time (``--speedup`` for faster) and serves
its samples the way a drive PC's hardware would: serial ADC frames on a
pseudo-terminal, CAN frames per ``config/p12.dbc``, or a Modbus TCP server.
The first line on stdout says where to connect; then it runs until killed
(or for ``--duration`` simulated seconds).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from observer.simulation.drive_stream import DriveStream

log = logging.getLogger(__name__)


def _common(p: argparse.ArgumentParser) -> None:
    from observer.estimation.motor import MOTORS

    p.add_argument("--motor", choices=sorted(MOTORS), default="p12", help="motor to simulate")
    p.add_argument("--noise", type=float, default=0.002, metavar="FRACTION",
                   help="sensor noise, fraction of each channel's rated value")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of duty cycles and noise")
    p.add_argument("--speedup", type=float, default=1.0, metavar="X",
                   help="serve X simulated seconds per wall second")  # fmt: skip
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S simulated seconds (default: run until killed)")  # fmt: skip
    from observer.commands.drive_options import add_drive_options

    add_drive_options(p)


def _bounded_int(low: int, high: int, what: str) -> Callable[[str], int]:
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{what} must be {low}-{high}, got {value}")
        return value

    return parse


_port = _bounded_int(0, 65535, "a TCP port")
_device_id = _bounded_int(0, 247, "a Modbus device id")


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="protocol", metavar="PROTOCOL", required=True)
    fmt = parser.formatter_class  # the CLI's: defaults shown where they say something

    s = sub.add_parser(
        "serial", formatter_class=fmt,
        help="serial ADC frames on a pseudo-terminal (prints the device path)",
        description="Serial ADC frames (format in drivers/serial_adc.py) on a new "
        "pseudo-terminal; prints its device path. Point [source.options] port at it, "
        "or at --link, which survives restarts.",
    )  # fmt: skip
    _common(s)
    s.add_argument("--rate", type=float, default=2000.0, metavar="HZ", help="sample rate (Hz)")
    s.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the device")
    s.add_argument("--baud", type=int, default=921600,
                   help="wire rate the frames must fit (a pty has no baud limit)")  # fmt: skip
    s.add_argument("--corrupt-every", type=int, default=0, metavar="N",
                   help="flip one bit in every N-th frame")  # fmt: skip
    s.add_argument("--garbage-every", type=int, default=0, metavar="N",
                   help="insert random bytes before every N-th frame")  # fmt: skip
    s.add_argument("--tear-every", type=int, default=0, metavar="N",
                   help="cut every N-th frame short")  # fmt: skip
    s.set_defaults(_run=_run_serial)

    c = sub.add_parser(
        "can", formatter_class=fmt,
        help="CAN frames per config/p12.dbc on a python-can bus",
        description="CAN frames per config/p12.dbc (two frames per sample) on a python-can "
        "bus. Across processes on this machine use udp_multicast (inside a network "
        "namespace: see the README); 'virtual' reaches only its own process, so it is "
        "refused here; on a drive PC use socketcan.",
    )  # fmt: skip
    _common(c)
    c.add_argument("--rate", type=float, default=1000.0, metavar="HZ", help="sample rate (Hz)")
    c.add_argument("--interface", default="udp_multicast", help="python-can interface")
    c.add_argument("--channel", default="239.74.163.2", help="python-can channel")
    c.add_argument("--bitrate", type=int, default=0, help="bus bitrate; 0 leaves it as is")
    c.add_argument("--dbc", default=None, help="DBC file (default: the bundled config/p12.dbc)")
    c.set_defaults(_run=_run_can)

    m = sub.add_parser(
        "modbus", formatter_class=fmt,
        help="a Modbus TCP server on 127.0.0.1 (prints host:port)",
        description="A Modbus TCP server whose registers hold the simulated drive's latest "
        "sample (map in drivers/fake_drive.py: counter, device time, float32, int16 and "
        "int32 copies); prints host:port.",
    )  # fmt: skip
    _common(m)
    m.add_argument("--rate", type=float, default=200.0, metavar="HZ",
                   help="the drive's sample (register update) rate (Hz)")  # fmt: skip
    m.add_argument("--host", default="127.0.0.1", help="address to listen on")
    m.add_argument("--port", type=_port, default=5020, help="TCP port (0: any free port)")
    m.add_argument("--device-id", type=_device_id, default=1, help="Modbus device (unit) id")
    m.add_argument("--framer", choices=("socket", "rtu"), default="socket",
                   help="Modbus TCP, or RTU frames over TCP (socket://host:port)")  # fmt: skip
    m.add_argument("--exception-every", type=int, default=0, metavar="N",
                   help="answer every N-th request with exception 6 (device busy)")  # fmt: skip
    m.add_argument("--stall-every", type=int, default=0, metavar="N",
                   help="answer every N-th request only after --stall-s")  # fmt: skip
    m.add_argument("--stall-s", type=float, default=0.5, help="delay of a stalled answer (s)")
    m.set_defaults(_run=_run_modbus)


def _stream(args: argparse.Namespace, rate: float) -> DriveStream:
    from observer.cli import UserError
    from observer.commands.drive_options import drive_from_args
    from observer.estimation.motor import MOTORS
    from observer.simulation.drive_stream import DriveStream

    if not rate > 0 or not args.speedup > 0 or args.noise < 0:
        raise UserError("--rate and --speedup must be > 0 and --noise >= 0")
    if args.duration is not None and not args.duration > 0:
        raise UserError("--duration must be > 0")
    drive, name = drive_from_args(args, rate)
    args.drive_name = name  # for the announcement
    try:
        return DriveStream(
            MOTORS[args.motor], sample_rate_hz=rate, noise=args.noise, seed=args.seed, drive=drive
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _stop_event() -> threading.Event:
    stop = threading.Event()

    def handler(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


def _announce(line: str) -> None:
    print(line, flush=True)


def _run_serial(args: argparse.Namespace) -> int:
    from drivers.fake_drive import FaultPlan, SerialFakeDrive
    from drivers.serial_adc import frame_size
    from observer.cli import UserError

    stream = _stream(args, args.rate)
    bits_per_s = args.rate * args.speedup * frame_size(5) * 10
    if bits_per_s > args.baud:
        raise UserError(
            f"{args.rate * args.speedup:g} frames/s of {frame_size(5)} bytes need "
            f"{bits_per_s:.0f} baud, more than --baud {args.baud}"
        )
    for name in ("corrupt_every", "garbage_every", "tear_every"):
        if getattr(args, name) < 0:
            raise UserError(f"--{name.replace('_', '-')} must be >= 0")
    faults = FaultPlan(args.corrupt_every, args.garbage_every, args.tear_every)
    try:
        drive = SerialFakeDrive(
            stream, speedup=args.speedup, link=args.link, faults=faults, seed=args.seed
        )
    except OSError as exc:
        raise UserError(f"cannot create the pseudo-terminal or link: {exc}") from exc
    stop = _stop_event()
    stream.prefetch()  # compile before announcing: no start-up burst
    where = drive.device_path + (f" (link {args.link})" if args.link else "")
    _announce(
        f"serial fake drive on {where}, {args.rate:g} Hz x{args.speedup:g}, drive {args.drive_name}"
    )
    try:
        drive.run(stop, args.duration)
    finally:
        drive.close()
        log.info(
            "sent %d frames, %d unsent (nobody reading)", drive.frames_sent, drive.unsent_frames
        )
    return 0


def _run_can(args: argparse.Namespace) -> int:
    import can

    from drivers.fake_drive import CanFakeDrive
    from observer.cli import UserError

    if args.interface == "virtual":
        raise UserError("the 'virtual' interface reaches only its own process; use udp_multicast")
    stream = _stream(args, args.rate)
    kwargs = {"bitrate": args.bitrate} if args.bitrate else {}
    try:
        bus = can.Bus(interface=args.interface, channel=args.channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError) as exc:
        raise UserError(f"cannot open CAN {args.interface} {args.channel}: {exc}") from exc
    try:
        drive = CanFakeDrive(stream, bus, speedup=args.speedup, dbc=args.dbc)
        stop = _stop_event()
        stream.prefetch()
        _announce(
            f"can fake drive on {args.interface} {args.channel}, {args.rate:g} Hz "
            f"x{args.speedup:g}, drive {args.drive_name}"
        )
        drive.run(stop, args.duration)
    except OSError as exc:
        raise UserError(f"cannot load the DBC: {exc}") from exc
    finally:
        bus.shutdown()
    return 0


def _run_modbus(args: argparse.Namespace) -> int:
    import asyncio

    from drivers.fake_drive import ModbusFakeDrive
    from observer.cli import UserError

    stream = _stream(args, args.rate)
    if args.exception_every < 0 or args.stall_every < 0 or args.stall_s < 0:
        raise UserError("--exception-every, --stall-every and --stall-s must be >= 0")
    drive = ModbusFakeDrive(
        stream, speedup=args.speedup, device_id=args.device_id,
        exception_every=args.exception_every, stall_every=args.stall_every,
        stall_s=args.stall_s, framer=args.framer,
    )  # fmt: skip

    async def serve() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, stop.set)
        try:
            host, port = await drive.start(args.host, args.port)
        except (OSError, RuntimeError) as exc:  # pymodbus raises RuntimeError when bind fails
            raise UserError(f"cannot listen on {args.host}:{args.port}: {exc}") from exc
        _announce(
            f"modbus fake drive on {host}:{port}, {args.rate:g} Hz x{args.speedup:g}, "
            f"drive {args.drive_name}"
        )
        try:
            if args.duration is None:
                await stop.wait()
            else:
                wall = args.duration / args.speedup
                try:
                    await asyncio.wait_for(stop.wait(), wall)
                except TimeoutError:
                    pass
        finally:
            await drive.stop()

    asyncio.run(serve())
    return 0


def main(args: argparse.Namespace) -> int:
    rc: int = args._run(args)
    sys.stdout.flush()
    return rc
