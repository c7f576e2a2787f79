"""One actuator interface: a command maps onto it in one place, for every kind of robot."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

from common.controller import RobotCommand
from common.controller.actuators import Actuators, apply_command
from common.messages import AgentCommand
from common.sim2d.agents import agent_type
from common.sim2d.world import EditError, World
from common.world.remote_robot import agent_command
from services.bridge.body import KinematicBody, RobotBody
from services.bridge.firmware import Firmware
from services.bridge.robot import KheperaRobot
from services.bridge.simbody import SimBody


class Recorded(Actuators):
    def __init__(self) -> None:
        self.calls: list[tuple[object, ...]] = []

    def set_speeds(self, left: int, right: int) -> None:
        self.calls.append(("speeds", left, right))

    def set_counters(self, left: int, right: int) -> None:
        self.calls.append(("counters", left, right))

    def set_leds(self, leds: Sequence[bool]) -> None:
        self.calls.append(("leds", *leds))

    def set_arm(self, position: int) -> None:
        self.calls.append(("arm", position))

    def set_grip(self, closed: bool) -> None:
        self.calls.append(("grip", closed))


def test_every_field_maps_in_the_wires_order() -> None:
    robot = Recorded()
    command = AgentCommand(
        agent="k0", speeds=(3, -4), counters=(1, 2), leds=[True, False], arm=200, grip=True
    )
    assert apply_command(command, robot)
    assert robot.calls == [
        ("speeds", 3, -4),
        ("counters", 1, 2),
        ("leds", True, False),
        ("arm", 200),
        ("grip", True),
    ]


def test_an_empty_command_sets_nothing() -> None:
    robot = Recorded()
    assert not apply_command(AgentCommand(agent="k0"), robot)
    assert robot.calls == []


@pytest.mark.parametrize(
    "command",
    [
        RobotCommand(speeds=(10, -127)),
        RobotCommand(counters=(5, 6)),
        RobotCommand(leds=(True, False)),
        RobotCommand(arm=165),
        RobotCommand(grip=True),
    ],
)
def test_the_controllers_command_and_the_wires_set_the_same(command: RobotCommand) -> None:
    """A field keeps its name from the controller to the world: both forms map alike."""
    direct, wired = Recorded(), Recorded()
    apply_command(command, direct)
    apply_command(agent_command("k0", command), wired)
    assert direct.calls == wired.calls


def test_a_world_robot_obeys_through_the_interface() -> None:
    world = World(600.0, 600.0, seed=1)
    world.add_agent("k0", agent_type("khepera"), 300.0, 300.0)
    world.add_agent("bare", agent_type("khepera"), 100.0, 100.0, gripper=False)
    robot = world.actuators(world.agent_slot("k0"))
    apply_command(AgentCommand(agent="k0", speeds=(200, -5), leds=[False, True, True]), robot)
    assert world.cmd[0].tolist() == [127.0, -5.0]  # clamped to the type's limit
    assert world.leds[0, :2].tolist() == [0, 1]  # the third LED is not a Khepera's
    apply_command(AgentCommand(agent="k0", grip=True), robot)
    assert world.fingers[0] == 1
    with pytest.raises(EditError, match="no gripper"):
        apply_command(AgentCommand(agent="bare", grip=True), world.actuators(1))


def test_the_emulated_body_shows_the_firmwares_leds() -> None:
    body = KinematicBody()
    firmware = Firmware(body)
    firmware.handle("L,1,1", now=0.0)
    assert body.leds == (False, True)
    firmware.handle("L,1,2", now=0.0)  # the firmware toggles; the body shows the result
    firmware.handle("L,0,2", now=0.0)
    assert body.leds == (True, False)
    firmware.handle("D,5,-5", now=0.0)
    assert body.speed() == (5, -5)


def test_every_kind_of_robot_has_every_actuator() -> None:
    """Simulated, emulated and real: each implements the one interface, by the same names."""
    names = sorted(n for n in vars(Actuators) if n.startswith("set_"))
    assert names == ["set_arm", "set_counters", "set_grip", "set_leds", "set_speeds"]
    world = World(600.0, 600.0, seed=1)
    world.add_agent("k0", agent_type("khepera"), 300.0, 300.0)
    robots = [world.actuators(0), KinematicBody(), SimBody(world), KheperaRobot("/dev/unopened")]
    for robot in robots:
        assert all(callable(getattr(robot, name)) for name in names), type(robot).__name__
    assert isinstance(KinematicBody(), RobotBody) and isinstance(SimBody(world), RobotBody)
