"""The emulated Khepera's firmware: one command line in, the exact reply bytes out.

Pure, no I/O: what the robot's microcontroller keeps (LEDs, PID gains, the
speed profile, the extension bus) plus a :class:`~services.bridge.body.RobotBody`
for everything physical. :class:`~services.bridge.emulator.KheperaEmulator`
serves it on a pty.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

from services.bridge.body import RobotBody
from services.bridge.protocol import (
    DEFAULT_DIALECT,
    GRIPPER_TURRET,
    INT32_MAX,
    INT32_MIN,
    SPEED_LIMIT,
    Dialect,
    ParsedCommand,
    clamp,
    format_reply,
    parse_command,
)

log = logging.getLogger("wart.bridge.emulator")

BANNER = "ROM of minirobot KHEPERA Version 5.02 Rev. 5.01"


class BadArguments(ValueError):
    """The command's arguments do not fit (the firmware answers as for an unknown command)."""


def _args(cmd: ParsedCommand, count: int, lo: int = INT32_MIN, hi: int = INT32_MAX) -> list[int]:
    if len(cmd.fields) != count:
        raise BadArguments(f"{cmd.letter} takes {count} arguments, got {len(cmd.fields)}")
    try:
        values = [int(f) for f in cmd.fields]
    except ValueError as exc:
        raise BadArguments(f"{cmd.letter}: {exc}") from exc
    if any(not lo <= v <= hi for v in values):
        raise BadArguments(f"{cmd.letter}: argument out of range {lo}..{hi}")
    return values


@dataclass
class Firmware:
    """The robot's command interpreter: one command line in, the exact reply bytes out."""

    body: RobotBody
    dialect: Dialect = DEFAULT_DIALECT
    bios: str = "5.02"
    protocol: str = "5.01"
    gripper: bool = True  # a gripper turret is mounted (T,1,... answered)
    gripper_version: tuple[int, int] = (1, 3)
    not_found_text: str = "Command not found"
    leds: list[int] = field(default_factory=lambda: [0, 0])
    speed_pid: tuple[int, int, int] = (3800, 800, 100)
    position_pid: tuple[int, int, int] = (3000, 20, 4000)
    profile: tuple[int, int, int, int] = (20, 64, 20, 64)
    bus: bytearray = field(default_factory=lambda: bytearray(64))

    def not_found(self) -> bytes:
        return self.not_found_text.encode("ascii") + self.dialect.reply_eol

    def handle(self, line: str, now: float | None = None) -> bytes:
        cmd = parse_command(line)
        if cmd is None:
            return self.not_found()
        self.body.advance(time.monotonic() if now is None else now)
        try:
            reply = self._dispatch(cmd)
        except BadArguments as exc:
            log.debug("emulator: %s", exc)
            return self.not_found()
        return reply if reply is not None else self.not_found()

    def reset(self) -> None:
        """A power-on reset: firmware defaults, body stopped and counters at zero."""
        self.leds = [0, 0]
        self.body.set_leds([False, False])
        self.speed_pid, self.position_pid = (3800, 800, 100), (3000, 20, 4000)
        self.profile = (20, 64, 20, 64)
        self.body.reset()

    def _reply(self, letter: str, *values: int | str) -> bytes:
        return format_reply(letter, *values, dialect=self.dialect)

    def _dispatch(self, cmd: ParsedCommand) -> bytes | None:
        b, letter = self.body, cmd.letter
        if letter == "A":
            self.speed_pid = tuple(_args(cmd, 3, 0))  # type: ignore[assignment]
        elif letter == "B":
            _args(cmd, 0)
            return self._reply("b", self.bios, self.protocol)
        elif letter == "C":
            left, right = _args(cmd, 2)
            p = self.profile
            b.move_to(left, right, (p[0], p[2]), (p[1], p[3]))
        elif letter == "D":
            left, right = _args(cmd, 2)
            b.set_speeds(clamp(left, SPEED_LIMIT), clamp(right, SPEED_LIMIT))
        elif letter == "E":
            _args(cmd, 0)
            return self._reply("e", *b.speed())
        elif letter == "F":
            self.position_pid = tuple(_args(cmd, 3, 0))  # type: ignore[assignment]
        elif letter == "G":
            b.set_counters(*_args(cmd, 2))
        elif letter == "H":
            _args(cmd, 0)
            return self._reply("h", *b.counters())
        elif letter == "I":
            (channel,) = _args(cmd, 1, 0, 255)
            return self._reply("i", b.analog(channel))
        elif letter == "J":
            self.profile = tuple(_args(cmd, 4, 0, 255))  # type: ignore[assignment]
        elif letter == "K":
            _args(cmd, 0)
            return self._reply("k", *b.motion_status())
        elif letter == "L":
            led, action = _args(cmd, 2, 0, 2)
            if led > 1:
                raise BadArguments("L: LED is 0 or 1")
            # The firmware keeps the LEDs (it toggles them); the body shows them.
            self.leds[led] = 1 - self.leds[led] if action == 2 else action
            b.set_leds([bool(on) for on in self.leds])
        elif letter == "N":
            _args(cmd, 0)
            return self._reply("n", *b.proximity())
        elif letter == "O":
            _args(cmd, 0)
            return self._reply("o", *b.ambient())
        elif letter == "P":
            b.set_pwm(*(clamp(v, 255) for v in _args(cmd, 2)))
        elif letter == "R":
            (addr,) = _args(cmd, 1, 0, 63)
            return self._reply("r", self.bus[addr])
        elif letter == "T":
            return self._turret(cmd)
        elif letter == "W":
            first, second = _args(cmd, 2, 0, 255)
            addr, value = (
                (first, second) if self.dialect.bus_write_order == "addr_value" else (second, first)
            )
            if addr > 63:
                raise BadArguments("W: bus address is 0..63")
            self.bus[addr] = value
        else:
            return None
        return self._reply(letter.lower())

    def _turret(self, cmd: ParsedCommand) -> bytes | None:
        if len(cmd.fields) < 2 or cmd.fields[0] != str(GRIPPER_TURRET) or not self.gripper:
            return None
        sub, rest = cmd.fields[1], ParsedCommand(cmd.fields[1], cmd.fields[2:])
        b = self.body

        def reply(*values: int) -> bytes:
            return self._reply("t", GRIPPER_TURRET, sub.lower(), *values)

        if sub == "B":
            _args(rest, 0)
            return reply(*self.gripper_version)
        if sub == "D":
            (closed,) = _args(rest, 1, 0, 1)
            b.set_grip(bool(closed))
            return reply()
        if sub == "E":
            (pos,) = _args(rest, 1, 0, 255)
            b.set_arm(pos)
            return reply()
        if sub == "F":
            _args(rest, 0)
            return reply(b.resistivity())
        if sub == "G":
            _args(rest, 0)
            return reply(b.object_present())
        if sub == "H":
            (which,) = _args(rest, 1, 0, 1)
            return reply(b.arm_position() if which else b.finger_position())
        if sub == "J":
            _args(rest, 0)
            return reply(0)
        return None
