"""The Khepera I serial protocol as pure values: requests to bytes, reply lines to typed results.

Nothing here touches a port. A :class:`Request` knows its exact bytes on the
wire and how to check and decode the one reply line that answers it; the
link (link.py) moves bytes, the emulator (emulator.py) speaks the other side
with the same helpers. Facts and the items that sources disagree on are in
docs/KHEPERA_PROTOCOL.md; the disagreeing ones live in :class:`Dialect`.

Wire shape: a command is one upper-case letter, then comma-separated decimal
integers, ended by CR (or LF: ``Dialect.command_eol``); a reply is the letter
in lower case, then comma-separated values, ended by CR LF.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Generic, Literal, TypeVar

T = TypeVar("T")

SPEED_LIMIT = 127  # pulses per 10 ms; clients clamp here (about 1 m/s)
PWM_LIMIT = 255
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
SENSOR_MAX = 1023  # 10-bit A/D
SENSOR_COUNT = 8
GRIPPER_TURRET = 1
# A reply line longer than this is noise: the longest real reply (n or o with
# eight 4-digit values) is under 50 characters.
MAX_LINE = 256

BANNER_RE = re.compile(r"ROM of minirobot KHEPERA", re.IGNORECASE)
_REPLY_RE = re.compile(r"^[a-z](,|$)")
_INT_RE = re.compile(r"^[+-]?\d{1,11}$")
_VERSION_RE = re.compile(r"^\d{1,3}(\.\d{1,3})?$")


# ---------------------------------------------------------------- errors


class ProtocolError(Exception):
    """A reply that does not answer the request as the protocol says."""


class MalformedReply(ProtocolError):
    """The reply letter matched but its values are wrong (count, type or range)."""


class CommandNotFound(ProtocolError):
    """The robot answered ``Command not found`` (or the ``z,`` variant of the same family)."""


# ---------------------------------------------------------------- dialect


@dataclass(frozen=True)
class Dialect:
    """Protocol details that sources disagree on (docs/KHEPERA_PROTOCOL.md "Uncertain items").

    command_eol: what ends a command we send (the manual allows CR or LF).
    reply_eol: what the robot ends a reply with (the emulator uses it; the link
        accepts CR, LF or both, so a host never depends on it).
    not_found: line prefixes that mean the robot did not know the command.
    bus_write_order: the order of W's two arguments, "addr_value" or "value_addr".
    """

    command_eol: bytes = b"\r"
    reply_eol: bytes = b"\r\n"
    not_found: tuple[str, ...] = ("Command not found", "z,")
    bus_write_order: Literal["addr_value", "value_addr"] = "addr_value"

    def __post_init__(self) -> None:
        if self.command_eol not in (b"\r", b"\n"):
            raise ValueError(f"command_eol must be CR or LF, not {self.command_eol!r}")
        if self.reply_eol not in (b"\r\n", b"\r", b"\n"):
            raise ValueError(f"reply_eol must be CR LF, CR or LF, not {self.reply_eol!r}")
        if self.bus_write_order not in ("addr_value", "value_addr"):
            raise ValueError(
                f"bus_write_order must be addr_value or value_addr, not {self.bus_write_order!r}"
            )

    def is_not_found(self, line: str) -> bool:
        return any(line.startswith(prefix) for prefix in self.not_found)


DEFAULT_DIALECT = Dialect()


# ---------------------------------------------------------------- typed results


@dataclass(frozen=True)
class Ack:
    """A reply that carries nothing but its letter (``d``, ``t,1,d``...)."""


ACK = Ack()


@dataclass(frozen=True)
class Version:
    bios: str
    protocol: str


@dataclass(frozen=True)
class WheelPair:
    """Left and right values of one kind: speeds (pulses/10 ms) or counters (pulses)."""

    left: int
    right: int


@dataclass(frozen=True)
class SensorArray:
    """Eight 10-bit readings in sensor order 0..7 (docs/KHEPERA_PROTOCOL.md sensor placement)."""

    values: tuple[int, ...]


@dataclass(frozen=True)
class WheelStatus:
    on_target: bool
    mode: int  # raw: which value means speed or position control is uncertain
    error: int


@dataclass(frozen=True)
class MotionStatus:
    """Reply to K: per wheel, on target, control mode, position error."""

    left: WheelStatus
    right: WheelStatus


@dataclass(frozen=True)
class Value:
    """One integer reading: an A/D channel, a bus byte, a gripper reading."""

    value: int


@dataclass(frozen=True)
class TurretVersion:
    version: int
    revision: int


@dataclass(frozen=True)
class Reply:
    """A reply line split into its letter and raw fields, before any checking of values."""

    letter: str
    fields: tuple[str, ...]


# ---------------------------------------------------------------- line parsing


def classify_line(
    line: str, dialect: Dialect = DEFAULT_DIALECT
) -> Literal["reply", "not_found", "banner", "other"]:
    """What kind of line the robot sent; "other" covers noise and anything unexpected."""
    if dialect.is_not_found(line):
        return "not_found"
    if BANNER_RE.search(line):
        return "banner"
    if _REPLY_RE.match(line):
        return "reply"
    return "other"


def split_reply(line: str) -> Reply:
    """Split ``e,3,-4`` into its letter and fields; raise MalformedReply for anything else."""
    if not _REPLY_RE.match(line):
        raise MalformedReply(f"not a reply line: {line!r}")
    parts = line.split(",")
    return Reply(parts[0], tuple(parts[1:]))


def _int(text: str, what: str, lo: int, hi: int) -> int:
    if not _INT_RE.match(text.strip()):
        raise MalformedReply(f"{what}: {text!r} is not an integer")
    value = int(text)
    if not lo <= value <= hi:
        raise MalformedReply(f"{what}: {value} out of range {lo}..{hi}")
    return value


def _ints(fields: Sequence[str], count: int, what: str, lo: int, hi: int) -> tuple[int, ...]:
    if len(fields) != count:
        raise MalformedReply(
            f"{what}: expected {count} values, got {len(fields)}: {','.join(fields)!r}"
        )
    return tuple(_int(f, f"{what}[{i}]", lo, hi) for i, f in enumerate(fields))


# ---------------------------------------------------------------- requests


@dataclass(frozen=True)
class Request(Generic[T]):
    """One command: its exact wire fields and the decoder of the reply fields that answer it.

    ``fields`` are what follows the letter (integers, or for a turret message
    the turret number and its own letter); ``reply_prefix`` is the part of the
    reply before the values (``t,1,h`` for a gripper position read).
    """

    letter: str
    fields: tuple[int | str, ...]
    decode_values: Callable[[tuple[str, ...]], T] = field(repr=False, compare=False)
    reply_prefix: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if len(self.letter) != 1 or not ("A" <= self.letter <= "Z"):
            raise ValueError(f"a command letter is one upper-case letter, not {self.letter!r}")

    @property
    def reply_letter(self) -> str:
        return self.letter.lower()

    def encode(self, dialect: Dialect = DEFAULT_DIALECT) -> bytes:
        text = ",".join([self.letter, *(str(f) for f in self.fields)])
        return text.encode("ascii") + dialect.command_eol

    def decode(self, reply: Reply) -> T:
        """Check the letter and prefix, then decode the values; MalformedReply on any mismatch."""
        if reply.letter != self.reply_letter:
            raise MalformedReply(f"reply {reply.letter!r} does not answer {self.letter!r}")
        n = len(self.reply_prefix)
        if tuple(f.strip() for f in reply.fields[:n]) != self.reply_prefix:
            raise MalformedReply(
                f"reply {','.join((reply.letter, *reply.fields))!r} does not start with "
                f"{','.join((reply.letter, *self.reply_prefix))!r}"
            )
        return self.decode_values(reply.fields[n:])

    def parse(self, line: str) -> T:
        return self.decode(split_reply(line))


# decoders, one per reply shape


def _ack(fields: tuple[str, ...]) -> Ack:
    if fields:
        raise MalformedReply(f"expected no values, got {','.join(fields)!r}")
    return ACK


def _version(fields: tuple[str, ...]) -> Version:
    if len(fields) != 2:
        raise MalformedReply(f"version: expected 2 values, got {len(fields)}")
    bios, proto = (f.strip() for f in fields)
    for name, text in (("bios", bios), ("protocol", proto)):
        if not _VERSION_RE.match(text):
            raise MalformedReply(f"version {name}: {text!r} is not a version number")
    return Version(bios, proto)


def _pair(lo: int, hi: int, what: str) -> Callable[[tuple[str, ...]], WheelPair]:
    def decode(fields: tuple[str, ...]) -> WheelPair:
        left, right = _ints(fields, 2, what, lo, hi)
        return WheelPair(left, right)

    return decode


def _sensors(what: str) -> Callable[[tuple[str, ...]], SensorArray]:
    def decode(fields: tuple[str, ...]) -> SensorArray:
        return SensorArray(_ints(fields, SENSOR_COUNT, what, 0, SENSOR_MAX))

    return decode


def _motion(fields: tuple[str, ...]) -> MotionStatus:
    t1, m1, e1, t2, m2, e2 = _ints(fields, 6, "motion status", INT32_MIN, INT32_MAX)
    return MotionStatus(WheelStatus(t1 != 0, m1, e1), WheelStatus(t2 != 0, m2, e2))


def _value(lo: int, hi: int, what: str) -> Callable[[tuple[str, ...]], Value]:
    def decode(fields: tuple[str, ...]) -> Value:
        return Value(_ints(fields, 1, what, lo, hi)[0])

    return decode


def _turret_version(fields: tuple[str, ...]) -> TurretVersion:
    v, r = _ints(fields, 2, "gripper version", 0, 255)
    return TurretVersion(v, r)


# argument checks: speeds and PWM are clamped (what every client does), the
# rest are refused when out of range because a wrong LED or address is a bug.


def clamp(value: int, limit: int) -> int:
    return max(-limit, min(limit, int(value)))


def _check(value: int, lo: int, hi: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{what} must be an int, not {type(value).__name__}")
    if not lo <= value <= hi:
        raise ValueError(f"{what} {value} out of range {lo}..{hi}")
    return value


def set_speed_pid(kp: int, ki: int, kd: int) -> Request[Ack]:
    """A: speed PID gains (default 3800, 800, 100)."""
    gains = tuple(_check(g, 0, INT32_MAX, "speed PID gain") for g in (kp, ki, kd))
    return Request("A", gains, _ack)


def read_version() -> Request[Version]:
    """B: BIOS and protocol versions; also how auto-detection recognises a robot."""
    return Request("B", (), _version)


def move_to(left: int, right: int) -> Request[Ack]:
    """C: move to absolute counter targets (pulses) with the J speed profile."""
    return Request(
        "C",
        (
            _check(left, INT32_MIN, INT32_MAX, "left target"),
            _check(right, INT32_MIN, INT32_MAX, "right target"),
        ),
        _ack,
    )


def set_speed(left: float, right: float) -> Request[Ack]:
    """D: wheel speeds in pulses per 10 ms, rounded and clamped to ±127."""
    return Request("D", (clamp(round(left), SPEED_LIMIT), clamp(round(right), SPEED_LIMIT)), _ack)


def read_speed() -> Request[WheelPair]:
    """E: current wheel speeds (pulses per 10 ms)."""
    return Request("E", (), _pair(-32768, 32767, "speed"))


def set_position_pid(kp: int, ki: int, kd: int) -> Request[Ack]:
    """F: position PID gains (default 3000, 20, 4000)."""
    gains = tuple(_check(g, 0, INT32_MAX, "position PID gain") for g in (kp, ki, kd))
    return Request("F", gains, _ack)


def set_counters(left: int, right: int) -> Request[Ack]:
    """G: set the 32-bit position counters."""
    return Request(
        "G",
        (
            _check(left, INT32_MIN, INT32_MAX, "left counter"),
            _check(right, INT32_MIN, INT32_MAX, "right counter"),
        ),
        _ack,
    )


def read_counters() -> Request[WheelPair]:
    """H: the position counters (pulses)."""
    return Request("H", (), _pair(INT32_MIN, INT32_MAX, "counter"))


def read_analog(channel: int) -> Request[Value]:
    """I: one 10-bit A/D channel (0 to 4.096 V)."""
    return Request(
        "I", (_check(channel, 0, 255, "A/D channel"),), _value(0, SENSOR_MAX, "A/D value")
    )


def set_speed_profile(
    vmax_left: int, acc_left: int, vmax_right: int, acc_right: int
) -> Request[Ack]:
    """J: the speed profile C moves with (defaults 20 and 64; acc unit 3.125 mm/s²)."""
    args = (
        _check(vmax_left, 0, SPEED_LIMIT, "left max speed"),
        _check(acc_left, 0, 255, "left acceleration"),
        _check(vmax_right, 0, SPEED_LIMIT, "right max speed"),
        _check(acc_right, 0, 255, "right acceleration"),
    )
    return Request("J", args, _ack)


def read_motion_status() -> Request[MotionStatus]:
    """K: per wheel, on target, control mode (polarity uncertain) and error."""
    return Request("K", (), _motion)


LED_OFF, LED_ON, LED_TOGGLE = 0, 1, 2


def set_led(led: int, action: int) -> Request[Ack]:
    """L: LED 0 or 1; action 0 off, 1 on, 2 toggle."""
    return Request("L", (_check(led, 0, 1, "LED"), _check(action, 0, 2, "LED action")), _ack)


def read_proximity() -> Request[SensorArray]:
    """N: the eight IR proximity readings, 0..1023, larger is closer."""
    return Request("N", (), _sensors("proximity"))


def read_ambient() -> Request[SensorArray]:
    """O: the eight ambient light readings, 0..1023, about 500 in the dark, smaller is brighter."""
    return Request("O", (), _sensors("ambient"))


def set_pwm(left: float, right: float) -> Request[Ack]:
    """P: open-loop motor PWM, clamped to ±255."""
    return Request("P", (clamp(round(left), PWM_LIMIT), clamp(round(right), PWM_LIMIT)), _ack)


def read_bus(addr: int) -> Request[Value]:
    """R: read one byte of the extension bus (address 0..63)."""
    return Request("R", (_check(addr, 0, 63, "bus address"),), _value(0, 255, "bus byte"))


def write_bus(addr: int, value: int, dialect: Dialect = DEFAULT_DIALECT) -> Request[Ack]:
    """W: write one byte of the extension bus; argument order per ``dialect`` (uncertain)."""
    a, v = _check(addr, 0, 63, "bus address"), _check(value, 0, 255, "bus byte")
    return Request("W", (a, v) if dialect.bus_write_order == "addr_value" else (v, a), _ack)


def raw(letter: str, *args: int) -> Request[Reply]:
    """Any letter with integer arguments; the reply as raw fields (tools and tests)."""
    return Request(
        letter,
        tuple(_check(a, INT32_MIN, INT32_MAX, "argument") for a in args),
        lambda fields: Reply(letter.lower(), fields),
    )


# ---------------------------------------------------------------- gripper turret (T,1,...)


def _turret(sub: str, args: tuple[int, ...], decode: Callable[[tuple[str, ...]], T]) -> Request[T]:
    return Request(
        "T", (GRIPPER_TURRET, sub, *args), decode, reply_prefix=(str(GRIPPER_TURRET), sub.lower())
    )


def gripper_version() -> Request[TurretVersion]:
    """T,1,B: gripper turret version and revision."""
    return _turret("B", (), _turret_version)


def gripper_fingers(closed: bool) -> Request[Ack]:
    """T,1,D,0 opens the fingers, T,1,D,1 closes them."""
    return _turret("D", (1 if closed else 0,), _ack)


ARM_UP, ARM_DOWN = 165, 255  # mechanical range of the arm position (docs/KHEPERA_PROTOCOL.md)


def gripper_arm(position: int) -> Request[Ack]:
    """T,1,E,pos: arm position 0..255 (mechanically about 165 up to 255 down)."""
    return _turret("E", (_check(position, 0, 255, "arm position"),), _ack)


def gripper_resistivity() -> Request[Value]:
    """T,1,F: resistivity of the object held between the fingers."""
    return _turret("F", (), _value(0, 255, "resistivity"))


def gripper_object() -> Request[Value]:
    """T,1,G: the object-presence light barrier between the fingers."""
    return _turret("G", (), _value(0, 255, "object presence"))


def gripper_finger_position() -> Request[Value]:
    """T,1,H,0: finger position."""
    return _turret("H", (0,), _value(0, 255, "finger position"))


def gripper_arm_position() -> Request[Value]:
    """T,1,H,1: arm position."""
    return _turret("H", (1,), _value(0, 255, "arm position"))


def gripper_jumpers() -> Request[Value]:
    """T,1,J: the turret's jumper settings."""
    return _turret("J", (), _value(0, 255, "jumpers"))


# ---------------------------------------------------------------- the robot side (emulator)


@dataclass(frozen=True)
class ParsedCommand:
    """A command line as the robot reads it: letter and raw fields."""

    letter: str
    fields: tuple[str, ...]


_COMMAND_RE = re.compile(r"^[A-Z](,[^,]*)*$")


def parse_command(line: str) -> ParsedCommand | None:
    """The robot's view of a line: None when it is not a command at all."""
    line = line.strip()
    if not _COMMAND_RE.match(line):
        return None
    parts = line.split(",")
    return ParsedCommand(parts[0], tuple(p.strip() for p in parts[1:]))


def format_reply(letter: str, *values: int | str, dialect: Dialect = DEFAULT_DIALECT) -> bytes:
    """``format_reply("e", 3, -4)`` gives ``b"e,3,-4\\r\\n"``."""
    return ",".join([letter, *(str(v) for v in values)]).encode("ascii") + dialect.reply_eol
