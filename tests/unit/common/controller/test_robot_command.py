"""The controller command is one typed schema: every field round-trips, bad ones say why."""

from __future__ import annotations

import pytest

from common.controller import RobotCommand
from common.world.remote_robot import agent_command

EVERY_FIELD = [
    RobotCommand(speeds=(10, -127)),
    RobotCommand(counters=(0, 2**31 - 1)),
    RobotCommand(leds=(True, False)),
    RobotCommand(arm=165),
    RobotCommand(grip=True),
]


@pytest.mark.parametrize("command", EVERY_FIELD, ids=lambda c: next(iter(c.to_dict())))
def test_every_field_round_trips_through_the_pipe_form(command: RobotCommand) -> None:
    assert RobotCommand.from_dict({"t": "cmd", **command.to_dict()}) == command


def test_the_agent_command_carries_every_field() -> None:
    assert agent_command("k0", EVERY_FIELD[0]).speeds == (10, -127)
    assert agent_command("k0", EVERY_FIELD[1]).counters == (0, 2**31 - 1)
    assert agent_command("k0", EVERY_FIELD[2]).leds == [True, False]
    assert agent_command("k0", EVERY_FIELD[3]).arm == 165
    assert agent_command("k0", EVERY_FIELD[4]).grip is True


@pytest.mark.parametrize(
    ("wire", "why"),
    [
        ({"speeds": [200, 0]}, "speeds must be two integers within ±127"),
        ({"speeds": [1.5, 0]}, "speeds must be two integers"),
        ({"leds": [1, 0]}, "leds must be two booleans"),
        ({"arm": 300}, "arm must be an integer 0..255"),
        ({"grip": "yes"}, "grip must be true or false"),
        ({"speeds": [1, 1], "arm": 3}, "exactly one of"),
        ({"fly": 1}, "unknown command fields: fly"),
        ({}, "exactly one of"),
    ],
)
def test_a_bad_command_is_refused_with_the_reason(wire: dict[str, object], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        RobotCommand.from_dict(wire)


@pytest.mark.parametrize(
    ("fields", "why"),
    [
        ({"speeds": (True, False)}, "speeds must be two integers"),
        ({"speeds": (128, 0)}, "speeds must be two integers within ±127"),
        ({"counters": (0, 2**31)}, "counters must be two integers"),
        ({"speeds": (1, 2, 3)}, "speeds must be two integers"),
        ({"speeds": [1, 2]}, "speeds must be two integers"),
        ({"speeds": (1, 1), "counters": (0, 0)}, "exactly one of"),
        ({"speeds": (1, 1), "grip": True}, "exactly one of"),
    ],
)
def test_the_constructor_refuses_what_the_wire_form_refuses(
    fields: dict[str, object], why: str
) -> None:
    # The usual speeds/counters command takes a shortcut check; these must not slip through it.
    with pytest.raises(ValueError, match=why):
        RobotCommand(**fields)  # type: ignore[arg-type]
