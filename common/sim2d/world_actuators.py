"""A world's actuators: what a command sets on a robot (common.controller.actuators).

The per-slot setters are the simulation's own API (a test or the engine's
swarm path sets every robot's speeds at once with ``set_speeds_all``);
``World.actuators(slot)`` is one robot as the one actuator interface the
engine, the bridge and the emulator share, so a command is mapped onto it in
one place (``apply_command``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from common.controller.actuators import Actuators
from common.sim2d import compiled
from common.sim2d.world_state import EditError

if TYPE_CHECKING:
    from common.sim2d.gripper import GripperTurrets
    from common.sim2d.world_state import WorldState


class WorldActuators:
    """What commands set on one world's robots, by slot: wheel speeds, counters, LEDs, gripper."""

    def __init__(self, state: WorldState, grippers: GripperTurrets) -> None:
        self._state = state
        self._grippers = grippers  # arm and grip are the gripper turrets' rules

    def actuators(self, slot: int) -> RobotActuators:
        """The robot in ``slot`` as :class:`common.controller.actuators.Actuators`."""
        return RobotActuators(self, slot)

    def set_speeds(self, slot: int, left: float, right: float) -> None:
        state = self._state
        top = state.tables.max_speed[slot]
        state.cmd[slot] = (float(np.clip(left, -top, top)), float(np.clip(right, -top, top)))

    def set_speeds_all(self, speeds: npt.ArrayLike) -> None:
        """Every agent's (left, right) at once, rounded and clamped per type: the bulk path."""
        s = np.asarray(speeds, dtype=np.float64)
        state = self._state
        cmd = state.cmd
        if s.shape != cmd.shape:
            raise ValueError(
                f"expected {cmd.shape} wheel speeds (one row per agent), got {s.shape}"
            )
        compiled.clamp_speeds(s, state.tables.max_speed, cmd)

    def set_counters(self, slot: int, left: float, right: float) -> None:
        self._state.counters[slot] = (left, right)

    def set_leds(self, slot: int, leds: Sequence[bool]) -> None:
        """LED i on or off as ``leds[i]``; LEDs the robot's type lacks are ignored."""
        state = self._state
        for led, on in enumerate(leds[: state.agents[slot].spec.leds]):
            state.leds[slot, led] = 1 if on else 0

    def set_arm(self, slot: int, position: int) -> None:
        if not self._grippers.set_arm(slot, position):
            raise EditError(f"{self._state.agents[slot].id} has no gripper")

    def set_grip(self, slot: int, closed: bool) -> None:
        if not self._grippers.set_grip(slot, closed):
            raise EditError(f"{self._state.agents[slot].id} has no gripper")


class RobotActuators(Actuators):
    """One robot of a World as :class:`common.controller.actuators.Actuators`.

    A view by slot, made per command (``World.actuators``): a slot changes
    when a robot before it is removed, so it is not kept across edits.
    A robot without a gripper refuses arm and grip with an EditError (a ValueError).
    """

    __slots__ = ("slot", "world_actuators")

    def __init__(self, world_actuators: WorldActuators, slot: int) -> None:
        self.world_actuators, self.slot = world_actuators, slot

    def set_speeds(self, left: int, right: int) -> None:
        self.world_actuators.set_speeds(self.slot, left, right)

    def set_counters(self, left: int, right: int) -> None:
        self.world_actuators.set_counters(self.slot, left, right)

    def set_leds(self, leds: Sequence[bool]) -> None:
        self.world_actuators.set_leds(self.slot, leds)

    def set_arm(self, position: int) -> None:
        self.world_actuators.set_arm(self.slot, position)

    def set_grip(self, closed: bool) -> None:
        self.world_actuators.set_grip(self.slot, closed)
