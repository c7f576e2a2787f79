"""An emulated Khepera I on a pseudo-terminal: what a host sees of the real robot, without one.

Layers:
- :class:`~services.bridge.firmware.Firmware` (firmware.py) answers one
  command line with the exact reply bytes (pure, no I/O): what the robot's
  microcontroller keeps (LEDs, PID gains, speed profile, extension bus) plus a
  :class:`~services.bridge.body.RobotBody` for everything physical.
- :class:`KheperaEmulator` puts it on a pty that pyserial opens like any
  port, with the robot's habits: the reset banner, replies split across
  writes, optional garbage lines, baud-rate pacing (8N2: baud/11 bytes/s),
  and unplug/replug at a stable symlink path (like /dev/ttyUSB0, which
  disappears when the cable is pulled and comes back when it is plugged in).

``wart khepera-emulator`` runs one from the command line (SIGUSR1 toggles
unplugged/plugged in).
"""

from __future__ import annotations

import contextlib
import logging
import os
import random
import select
import signal
import sys
import threading
import time
import tty
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType, TracebackType
from typing import TYPE_CHECKING

from common.cli import parse, parser
from common.service import stop_on_signals
from services.bridge.body import KinematicBody, RobotBody
from services.bridge.firmware import BANNER, Firmware
from services.bridge.link import BAUD_RATES
from services.bridge.protocol import (
    DEFAULT_DIALECT,
    Dialect,
)

if TYPE_CHECKING:
    from services.bridge.simbody import SimBody

log = logging.getLogger("wart.bridge.emulator")


@dataclass(frozen=True)
class EmulatorOptions:
    """How the emulated robot behaves on the wire.

    pace: deliver bytes no faster than the baud rate allows (8N2: baud/11
        bytes/s, both directions), so latency benchmarks are realistic.
    split: write each reply in this many pieces, ``split_gap`` seconds apart
        (a real robot's reply often arrives in several reads).
    banner: print the reset banner when plugged in (power-on).
    garbage_every: write a noise line before every Nth reply (0: never).
    reply_delay: the firmware's own think time before it answers.
    link_path: a stable symlink to the current pty (None: only the pty path).
    """

    baud: int = 38400
    pace: bool = False
    split: int = 1
    split_gap: float = 0.002
    banner: bool = True
    garbage_every: int = 0
    reply_delay: float = 0.0
    link_path: str | None = None
    seed: int = 0
    dialect: Dialect = DEFAULT_DIALECT
    gripper: bool = True
    not_found_text: str = "Command not found"

    def __post_init__(self) -> None:
        if self.baud not in BAUD_RATES:
            raise ValueError(f"baud {self.baud} not one of {BAUD_RATES}")
        if not 1 <= self.split <= 64:
            raise ValueError(f"split {self.split} out of range 1..64")
        if self.garbage_every < 0 or self.split_gap < 0 or self.reply_delay < 0:
            raise ValueError("garbage_every, split_gap and reply_delay must not be negative")

    @property
    def bytes_per_second(self) -> float:
        return self.baud / 11  # start bit, 8 data bits, 2 stop bits


class KheperaEmulator:
    """A Khepera on a pty. ``port`` is what a host opens (the stable link, else the pty)."""

    def __init__(
        self, body: RobotBody | None = None, options: EmulatorOptions | None = None
    ) -> None:
        self.options = options or EmulatorOptions()
        self.body: RobotBody = body if body is not None else KinematicBody()
        self.firmware = Firmware(
            self.body,
            self.options.dialect,
            gripper=self.options.gripper,
            not_found_text=self.options.not_found_text,
        )
        self.received: list[bytes] = []  # every command line as it arrived, terminator included
        self.replies = 0
        self._rng = random.Random(self.options.seed)
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._pty_path: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._pending: list[bytes] = []  # lines to write before the next reply (banner, garbage)
        self._wire_free = 0.0  # pacing: when the host-to-robot direction is next idle

    # ------------------------------------------------------------ lifecycle

    @property
    def plugged(self) -> bool:
        return self._master is not None

    @property
    def pty_path(self) -> str | None:
        return self._pty_path

    @property
    def port(self) -> str:
        if self.options.link_path:
            return self.options.link_path
        if self._pty_path is None:
            raise RuntimeError("emulator is not plugged in")
        return self._pty_path

    def start(self) -> KheperaEmulator:
        self.plug()
        return self

    def stop(self) -> None:
        self.unplug()

    def __enter__(self) -> KheperaEmulator:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def plug(self) -> None:
        """Power on at a new pty (the stable link, if any, now points at it)."""
        with self._lock:
            if self._master is not None:
                return
            master, slave = os.openpty()
            # Raw at once: with the default line discipline the slave would echo
            # our banner back to us before pyserial sets its own raw mode.
            tty.setraw(slave)
            self._master, self._slave, self._pty_path = master, slave, os.ttyname(slave)
            self._stop.clear()
            self._pending.clear()
            self.firmware.reset()
            if self.options.banner:
                # The robot prints its banner at power-on, whether or not anyone listens.
                self._pending.append(b"\r\n" + BANNER.encode("ascii") + b"\r\n")
            if self.options.link_path:
                tmp = f"{self.options.link_path}.{os.getpid()}.tmp"
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(tmp)
                os.symlink(self._pty_path, tmp)
                os.replace(tmp, self.options.link_path)
            self._thread = threading.Thread(
                target=self._serve, name="khepera-emulator", daemon=True
            )
            self._thread.start()
            log.info("emulated Khepera plugged in at %s", self.port)

    def unplug(self) -> None:
        """Pull the cable: the pty goes away (hosts get EIO) and the stable link disappears."""
        with self._lock:
            if self._master is None:
                return
            self._stop.set()
            thread = self._thread
        if thread is not None:
            thread.join(2.0)
        with self._lock:
            if self.options.link_path:
                with contextlib.suppress(FileNotFoundError):
                    if os.readlink(self.options.link_path) == self._pty_path:
                        os.unlink(self.options.link_path)
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
            self._thread = None
            log.info("emulated Khepera unplugged (%s)", self._pty_path)

    def replug(self) -> None:
        self.unplug()
        self.plug()

    # ------------------------------------------------------------ faults a test can ask for

    def inject_banner(self) -> None:
        """The reset banner before the next reply (a robot that rebooted mid-stream)."""
        with self._lock:
            self.firmware.reset()
            self._pending.append(b"\r\n" + BANNER.encode("ascii") + b"\r\n")

    def inject_line(self, line: bytes) -> None:
        """Any bytes (noise, a stale reply) before the next reply."""
        with self._lock:
            self._pending.append(line)

    # ------------------------------------------------------------ the I/O thread

    def _serve(self) -> None:
        master = self._master
        assert master is not None
        buf = bytearray()
        # A banner at power-on goes out at once, not only before the first reply.
        self._flush_pending(master)
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([master], [], [], 0.05)
                if not ready:
                    continue
                data = os.read(master, 4096)
            except OSError as exc:
                log.debug("emulator read: %s", exc)
                return
            if not data:
                continue
            if self.options.pace:
                # The bytes took this long on a real wire; the robot sees the line
                # only once its last byte has arrived.
                now = time.monotonic()
                self._wire_free = (
                    max(self._wire_free, now) + len(data) / self.options.bytes_per_second
                )
            buf += data
            while True:
                ends = [i for i in (buf.find(b"\r"), buf.find(b"\n")) if i >= 0]
                if not ends:
                    break
                end = min(ends)
                raw = bytes(buf[: end + 1])
                del buf[: end + 1]
                if raw in (b"\r", b"\n"):
                    continue  # the LF of a CR LF, or a blank line
                self.received.append(raw)
                if not self._answer(master, raw):
                    return
            if len(buf) > 1024:
                buf.clear()  # a host streaming garbage without line ends

    def _answer(self, master: int, raw: bytes) -> bool:
        if self.options.pace:
            self._sleep_until(self._wire_free)
        if self.options.reply_delay:
            time.sleep(self.options.reply_delay)
        with self._lock:
            reply = self.firmware.handle(raw.decode("ascii", "replace"))
            self.replies += 1
            if self.options.garbage_every and self.replies % self.options.garbage_every == 0:
                self._pending.append(self._garbage())
        if not self._flush_pending(master):
            return False
        return self._write(master, reply, self.options.split)

    def _garbage(self) -> bytes:
        noise = bytes(
            self._rng.choice(b"#%&*@~^!?$0123456789ABCXYZ") for _ in range(self._rng.randint(3, 20))
        )
        return b"\xfe" + noise + b"\r\n"

    def _flush_pending(self, master: int) -> bool:
        with self._lock:
            pending, self._pending = self._pending, []
        return all(self._write(master, line, 1) for line in pending)

    def _write(self, master: int, data: bytes, pieces: int) -> bool:
        size = max(1, -(-len(data) // pieces))
        chunks = [data[i : i + size] for i in range(0, len(data), size)]
        for n, chunk in enumerate(chunks):
            if self.options.pace:
                time.sleep(len(chunk) / self.options.bytes_per_second)
            try:
                os.write(master, chunk)
            except OSError as exc:
                log.debug("emulator write: %s", exc)
                return False
            if n + 1 < len(chunks) and self.options.split_gap:
                time.sleep(self.options.split_gap)
        return True

    @staticmethod
    def _sleep_until(t: float) -> None:
        delay = t - time.monotonic()
        if delay > 0:
            time.sleep(delay)


# ---------------------------------------------------------------- wart khepera-emulator


def main(argv: Sequence[str] | None = None, prog: str = "wart khepera-emulator") -> int:

    p = parser(
        prog,
        "An emulated Khepera I on a pseudo-terminal: open the printed path like a serial port.\n"
        "SIGUSR1 unplugs it (the link path disappears) and plugs it back in; Ctrl-C stops it.",
        network=False,
    )
    p.add_argument(
        "--link",
        metavar="PATH",
        help="a stable symlink to the pty, like /dev/ttyUSB0 (e.g. /tmp/khepera0)",
    )
    p.add_argument(
        "--baud",
        type=int,
        choices=BAUD_RATES,
        default=38400,
        help="baud rate for pacing (default 38400)",
    )
    p.add_argument(
        "--pace", action="store_true", help="deliver bytes no faster than the baud rate allows"
    )
    p.add_argument(
        "--split", type=int, default=1, metavar="N", help="write each reply in N pieces (default 1)"
    )
    p.add_argument(
        "--garbage-every",
        type=int,
        default=0,
        metavar="N",
        help="a noise line before every Nth reply",
    )
    p.add_argument(
        "--no-banner", action="store_true", help="do not print the reset banner at power-on"
    )
    p.add_argument(
        "--no-gripper", action="store_true", help="no gripper turret (T,1,... not answered)"
    )
    p.add_argument(
        "--not-found",
        choices=["plain", "z"],
        default="plain",
        help="unknown-command reply: 'Command not found' or the 'z,' variant",
    )
    p.add_argument(
        "--eol",
        choices=["crlf", "cr", "lf"],
        default="crlf",
        help="reply terminator (default crlf)",
    )
    p.add_argument(
        "--map",
        type=Path,
        metavar="FILE",
        help="back the robot with a Sim2D Khepera in this map (sensors see its walls, lamps, "
        "balls); without it, a kinematic body with fixed sensor readings",
    )
    p.add_argument(
        "--agent", metavar="ID", help="which agent of the map is this robot (default: the first)"
    )
    p.add_argument("--seed", type=int, default=0, help="the map's sensor-noise seed (default 0)")
    p.add_argument(
        "--slip",
        type=float,
        default=0.0,
        metavar="FRACTION",
        help="with --map: the wheels slip, the left by FRACTION, the right by half of it "
        "(0 to 0.5, default 0): the counters overstate the motion, so odometry drifts "
        "as a real robot's does",
    )
    p.add_argument(
        "--truth",
        type=Path,
        metavar="FILE",
        help="with --map: write the robots' true poses to FILE ~30 times a second, for "
        "`wart camera --source synthetic:FILE`",
    )
    p.add_argument(
        "--body",
        type=Path,
        metavar="FILE",
        help="with --map: the robot's true parameters (TOML: wheel_scale, wheel_base_mm, "
        "latency_s, ir_gain, ir_noise_counts, seed; services/bridge/body_truth.py), what "
        "`wart calibrate` is tested against; replaces --slip",
    )
    args, _ = parse(p, argv)
    if args.agent is not None and args.map is None:
        p.error("--agent needs --map")
    if (args.slip or args.truth is not None or args.body is not None) and args.map is None:
        p.error("--slip, --truth and --body need --map (a simulated body)")
    if args.slip and args.body is not None:
        p.error("--slip or --body, not both (a body file says each wheel's grip)")
    if not 0.0 <= args.slip < 0.5:
        p.error(f"--slip must be 0 to 0.5 (a fraction of the wheels' motion); got {args.slip}")
    if not 1 <= args.split <= 64:
        p.error("--split must be 1..64")
    if args.garbage_every < 0:
        p.error("--garbage-every must not be negative")
    eol = {"crlf": b"\r\n", "cr": b"\r", "lf": b"\n"}[args.eol]
    options = EmulatorOptions(
        baud=args.baud,
        pace=args.pace,
        split=args.split,
        banner=not args.no_banner,
        garbage_every=args.garbage_every,
        link_path=args.link,
        gripper=not args.no_gripper,
        not_found_text="Command not found" if args.not_found == "plain" else "z,Command not found",
        dialect=Dialect(reply_eol=eol),
    )
    body: RobotBody | None = None
    sim: SimBody | None = None
    if args.map is not None:
        # Sim2D (pymunk, numba's compiled kernels) loads only for a simulated body:
        # a scripted emulator starts in a fraction of the time without it.
        from common.sim2d.maps import MapError
        from services.bridge.body_truth import BodyTruth
        from services.bridge.simbody import SimBody

        try:
            truth_of_body = None if args.body is None else BodyTruth.read(args.body)
            sim = SimBody.from_map(
                args.map,
                args.agent,
                seed=args.seed,
                slip=args.slip,
                truth=args.truth,
                body=truth_of_body,
            )
        except (MapError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            return 2
        body = sim.start()
    emulator = KheperaEmulator(body, options=options)
    stop = stop_on_signals()
    toggle = threading.Event()

    def on_toggle(signum: int, frame: FrameType | None) -> None:
        toggle.set()

    signal.signal(signal.SIGUSR1, on_toggle)
    try:
        emulator.start()
    except OSError as exc:
        print(f"error: cannot create the pty or link: {exc}", flush=True)
        if sim is not None:
            sim.stop()
        return 1
    where = f" in {args.map} as {sim.agent}" if sim is not None else ""
    print(
        f"emulated Khepera at {emulator.pty_path}"
        + (f" (link {args.link})" if args.link else "")
        + where,
        flush=True,
    )
    try:
        while not stop.wait(0.1):
            if toggle.is_set():
                toggle.clear()
                if emulator.plugged:
                    emulator.unplug()
                    print("unplugged", flush=True)
                else:
                    emulator.plug()
                    print(f"plugged in at {emulator.pty_path}", flush=True)
    finally:
        emulator.stop()
        if sim is not None:
            sim.stop()
    return 0
