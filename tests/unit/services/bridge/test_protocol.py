"""The Khepera serial protocol: exact bytes of each command, exact replies, bad replies refused."""

from __future__ import annotations

from typing import Any

import pytest

from services.bridge import protocol as P

# (request, exact bytes on the wire, exact reply line, decoded value)
CASES: list[tuple[P.Request[Any], bytes, str, object]] = [
    (P.set_speed_pid(3800, 800, 100), b"A,3800,800,100\r", "a", P.ACK),
    (P.read_version(), b"B\r", "b,5.02,5.01", P.Version("5.02", "5.01")),
    (P.move_to(1000, -2000), b"C,1000,-2000\r", "c", P.ACK),
    (P.set_speed(5, 5), b"D,5,5\r", "d", P.ACK),
    (P.read_speed(), b"E\r", "e,12,-7", P.WheelPair(12, -7)),
    (P.set_position_pid(3000, 20, 4000), b"F,3000,20,4000\r", "f", P.ACK),
    (P.set_counters(0, -5), b"G,0,-5\r", "g", P.ACK),
    (P.read_counters(), b"H\r", "h,123456,-2147483648", P.WheelPair(123456, -(2**31))),
    (P.read_analog(3), b"I,3\r", "i,512", P.Value(512)),
    (P.set_speed_profile(20, 64, 20, 64), b"J,20,64,20,64\r", "j", P.ACK),
    (
        P.read_motion_status(),
        b"K\r",
        "k,1,0,0,0,0,-12",
        P.MotionStatus(P.WheelStatus(True, 0, 0), P.WheelStatus(False, 0, -12)),
    ),
    (P.set_led(1, P.LED_TOGGLE), b"L,1,2\r", "l", P.ACK),
    (
        P.read_proximity(),
        b"N\r",
        "n,12,0,3,1023,40,0,0,7",
        P.SensorArray((12, 0, 3, 1023, 40, 0, 0, 7)),
    ),
    (
        P.read_ambient(),
        b"O\r",
        "o,500,498,480,100,50,499,500,501",
        P.SensorArray((500, 498, 480, 100, 50, 499, 500, 501)),
    ),
    (P.set_pwm(-255, 100), b"P,-255,100\r", "p", P.ACK),
    (P.read_bus(63), b"R,63\r", "r,255", P.Value(255)),
    (P.write_bus(7, 200), b"W,7,200\r", "w", P.ACK),
    (P.gripper_version(), b"T,1,B\r", "t,1,b,1,3", P.TurretVersion(1, 3)),
    (P.gripper_fingers(False), b"T,1,D,0\r", "t,1,d", P.ACK),
    (P.gripper_fingers(True), b"T,1,D,1\r", "t,1,d", P.ACK),
    (P.gripper_arm(P.ARM_UP), b"T,1,E,165\r", "t,1,e", P.ACK),
    (P.gripper_resistivity(), b"T,1,F\r", "t,1,f,87", P.Value(87)),
    (P.gripper_object(), b"T,1,G\r", "t,1,g,1", P.Value(1)),
    (P.gripper_finger_position(), b"T,1,H,0\r", "t,1,h,200", P.Value(200)),
    (P.gripper_arm_position(), b"T,1,H,1\r", "t,1,h,255", P.Value(255)),
    (P.gripper_jumpers(), b"T,1,J\r", "t,1,j,0", P.Value(0)),
]


@pytest.mark.parametrize(("request_", "wire", "reply", "value"), CASES, ids=lambda c: None)
def test_exact_bytes_and_reply(
    request_: P.Request[Any], wire: bytes, reply: str, value: object
) -> None:
    assert request_.encode() == wire
    assert request_.parse(reply) == value


def test_lf_terminator_is_configurable() -> None:
    assert P.set_speed(1, 2).encode(P.Dialect(command_eol=b"\n")) == b"D,1,2\n"
    with pytest.raises(ValueError, match="CR or LF"):
        P.Dialect(command_eol=b"\r\n")


def test_speed_and_pwm_are_rounded_and_clamped() -> None:
    assert P.set_speed(300, -1000).encode() == b"D,127,-127\r"
    assert P.set_speed(2.6, -2.4).encode() == b"D,3,-2\r"
    assert P.set_pwm(999, -999).encode() == b"P,255,-255\r"


def test_bus_write_order_is_configurable() -> None:
    swapped = P.Dialect(bus_write_order="value_addr")
    assert P.write_bus(7, 200, swapped).encode() == b"W,200,7\r"


@pytest.mark.parametrize(
    "make",
    [
        lambda: P.set_led(2, 0),
        lambda: P.set_led(0, 3),
        lambda: P.read_bus(64),
        lambda: P.write_bus(0, 256),
        lambda: P.gripper_arm(256),
        lambda: P.set_counters(2**31, 0),
        lambda: P.set_speed_profile(200, 0, 0, 0),
        lambda: P.set_speed_pid(-1, 0, 0),
    ],
)
def test_out_of_range_arguments_are_refused(make: Any) -> None:
    with pytest.raises(ValueError, match="out of range"):
        make()


def test_non_integer_argument_is_refused() -> None:
    with pytest.raises(TypeError, match="must be an int"):
        P.set_led(True, 1)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("request_", "reply", "message"),
    [
        (P.read_proximity(), "n,1,2,3", "expected 8 values, got 3"),
        (P.read_proximity(), "n,1,2,3,4,5,6,7,1024", "out of range 0..1023"),
        (P.read_ambient(), "o,1,2,3,x,5,6,7,8", "not an integer"),
        (P.read_speed(), "e,1", "expected 2 values"),
        (P.read_version(), "b,five,5.01", "not a version number"),
        (P.set_speed(0, 0), "d,1", "expected no values"),
        (P.read_counters(), "e,1,2", "does not answer 'H'"),
        (P.gripper_arm_position(), "t,1,g,3", "does not start with 't,1,h'"),
        (P.gripper_arm_position(), "t,2,h,3", "does not start with 't,1,h'"),
        (P.read_speed(), "E,1,2", "not a reply line"),
    ],
)
def test_malformed_replies_are_rejected_clearly(
    request_: P.Request[Any], reply: str, message: str
) -> None:
    with pytest.raises(P.MalformedReply, match=message):
        request_.parse(reply)


@pytest.mark.parametrize(
    ("line", "kind"),
    [
        ("d", "reply"),
        ("n,1,2,3,4,5,6,7,8", "reply"),
        ("Command not found", "not_found"),
        ("z,Command not found", "not_found"),
        ("ROM of minirobot KHEPERA Version 5.02 Rev. 5.01", "banner"),
        ("garbage", "other"),
        ("\ufffd#@!", "other"),
        ("", "other"),
    ],
)
def test_lines_are_classified(line: str, kind: str) -> None:
    assert P.classify_line(line) == kind


def test_robot_side_helpers() -> None:
    assert P.parse_command("D,5,-5\r") == P.ParsedCommand("D", ("5", "-5"))
    assert P.parse_command("T,1,D,1") == P.ParsedCommand("T", ("1", "D", "1"))
    assert P.parse_command("d,5") is None
    assert P.format_reply("e", 3, -4) == b"e,3,-4\r\n"
    assert P.format_reply("d", dialect=P.Dialect(reply_eol=b"\r")) == b"d\r"
