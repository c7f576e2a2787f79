"""The controller API follows the robot: its file's components, by their names, checked.

A controller sees exactly its robot's components: the drive, rings, LEDs and
gripper the type has, and each batched sensor under the name the robot file
gives it. Check refuses a call the chosen robot does not have, saying why; the
readings travel by name from the world (SensorSample.parts) through the runner's
pipe to the controller.
"""

from __future__ import annotations

import pytest

from common.controller import Khepera, KheperaState, RobotCommand
from common.controller.advice import check_source
from common.controller.pipe import State, decode_to_child, encode
from common.messages import SensorSample, decode
from common.messages.base import encode as encode_message
from common.robots import registry
from common.robots.describe import robot_api
from common.robots.robotfile import parse
from common.sim2d.world import World
from common.world.packing import samples, snapshot
from common.world.remote_robot import state_from_sample
from tests.kit.robots import wheeled_robot

REG = registry.build(plugins=False)
LINE_BOT = parse(
    wheeled_robot(
        "liner",
        """
[components.line]
type = "floor_sensor"
points = [[20.0, -8.0], [20.0, 8.0]]
noise = 0.0
""",
    ),
    "liner.toml",
    REG.components,
)

SOURCE = """\
from common.controller import Controller


class Follow(Controller):
    def do_work(self, robot):
        left, right = robot.line().values
        robot.set_speeds(right // 10, left // 10)
        robot.close_gripper()
        robot.set_leds(True, False)
        robot.lnie()
"""


def _messages(api) -> list[str]:  # type: ignore[no-untyped-def]
    return [str(p) for p in check_source(SOURCE.encode(), "follow.py", api)]


def test_check_follows_the_chosen_robot_s_components() -> None:
    assert _messages(robot_api(LINE_BOT)) == [
        "line 8: robot.close_gripper: this robot (liner) has no gripper",
        "line 9: robot.set_leds: this robot (liner) has no LEDs",
        "line 10: robot.lnie does not exist on this robot (liner) (did you mean line?)",
    ]
    epuck = _messages(robot_api(REG.robots["epuck"]))
    assert "line 6: robot.line does not exist on this robot (epuck)" in epuck[0]
    assert "line 8: robot.close_gripper: this robot (epuck) has no gripper" in epuck
    khepera = _messages(robot_api(REG.robots["khepera"]))
    assert not any("close_gripper" in m or "set_leds" in m for m in khepera)
    # A Khepera whose map takes its gripper off has none either.
    no_gripper = _messages(robot_api(REG.robots["khepera"], gripper=False))
    assert "line 8: robot.close_gripper: this robot (khepera) has no gripper" in no_gripper


class _Link:
    def __init__(self, state: KheperaState) -> None:
        self.state = state
        self.sent: list[RobotCommand] = []

    def latest(self) -> KheperaState:
        return self.state

    def send(self, command: RobotCommand) -> None:
        self.sent.append(command)


def test_the_world_s_readings_reach_the_controller_by_their_file_names() -> None:
    world = World(400, 300, seed=1)
    world.add_agent("l1", LINE_BOT, 100, 100, 0.0)
    (sample,) = samples(world, [0])
    assert sample.parts == {"line": [255, 255]}
    wire = decode(encode_message(sample), SensorSample)
    state = state_from_sample(wire)
    # the runner's pipe to the sandboxed child
    (child_state,) = [decode_to_child(encode(State(state)))]
    assert isinstance(child_state, State)
    robot = Khepera(_Link(child_state.state))
    assert robot.line().values == (255, 255)
    assert robot.read("line").values == (255, 255)
    assert robot.sensors() == ("line",) and robot.has("line") and not robot.has("eye")
    with pytest.raises(AttributeError, match=r"this robot has no 'eye'.*\(line\)"):
        robot.eye()
    info = snapshot(world).agents[0]
    assert info.components == [("body", "body"), ("drive", "drive"), ("line", "sensor")]


@pytest.mark.parametrize(
    ("parts", "message"),
    [
        ({"Line": [1]}, "is not a sensor name"),
        ({"line": [1.5]}, "expected 32-bit integers"),
        ({"line": list(range(65))}, "at most 64 integers"),
        ({f"s{i}": [] for i in range(33)}, "at most 32 sensors"),
    ],
)
def test_bad_readings_on_the_pipe_are_refused(parts: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        KheperaState.from_dict({**KheperaState().to_dict(), "parts": parts})
