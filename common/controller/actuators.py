"""One robot's actuators, one interface: what a command can set, whoever carries it out.

Like ARGoS's and Enki's control interfaces, this is the contract between a
command and a robot, separate from its implementations: a simulated robot
(``common.sim2d.world.World.actuators(slot)``), a real Khepera on a serial port
(``services.bridge.robot.KheperaRobot``) and the emulated Khepera's body
(``services.bridge.body.RobotBody``) each implement it. A command's fields carry
the same names from the controller to the world: ``speeds``, ``counters``,
``leds``, ``arm``, ``grip`` (:class:`common.controller.RobotCommand`, the wire's
``AgentCommand``), and :func:`apply_command` maps them onto the actuators in
one place, which the engine, the bridge and the runner's dry run all call.

Standard library only, like the rest of this package: the sandbox copies it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol


class Actuators(Protocol):
    """The actuators of one robot. Values are in the Khepera's units.

    A robot without a gripper (or with fewer LEDs) may refuse the calls it
    cannot obey by raising ``ValueError``; LEDs beyond the robot's count are
    ignored, so a controller written for two LEDs runs on any robot.
    """

    def set_speeds(self, left: int, right: int) -> None:
        """Wheel speeds in pulses per 10 ms (about 8 mm/s each), within ±127."""

    def set_counters(self, left: int, right: int) -> None:
        """Set the wheels' position counters, in pulses."""

    def set_leds(self, leds: Sequence[bool]) -> None:
        """Turn LED ``i`` on or off as ``leds[i]`` says."""

    def set_arm(self, position: int) -> None:
        """Aim the gripper's arm, 0..255 (about 165 up to 255 down)."""

    def set_grip(self, closed: bool) -> None:
        """Close the gripper's fingers (gripping what is between them) or open them."""


class CommandFields(Protocol):
    """A command as both of its forms carry it (RobotCommand, the wire's AgentCommand).

    Each field left None leaves its actuator alone.
    """

    @property
    def speeds(self) -> tuple[int, int] | None: ...

    @property
    def counters(self) -> tuple[int, int] | None: ...

    @property
    def leds(self) -> Sequence[bool] | None: ...

    @property
    def arm(self) -> int | None: ...

    @property
    def grip(self) -> bool | None: ...


def apply_command(command: CommandFields, robot: Actuators) -> bool:
    """Set each actuator the command names, in a fixed order; False if it names none.

    The order is the wire's (speeds, counters, LEDs, arm, fingers): the bridge
    queues one serial request per actuator in this order. An empty command
    only feeds the watchdog (the caller's to do).
    """
    applied = False
    if command.speeds is not None:
        robot.set_speeds(*command.speeds)
        applied = True
    if command.counters is not None:
        robot.set_counters(*command.counters)
        applied = True
    if command.leds is not None:
        robot.set_leds(command.leds)
        applied = True
    if command.arm is not None:
        robot.set_arm(command.arm)
        applied = True
    if command.grip is not None:
        robot.set_grip(command.grip)
        applied = True
    return applied
