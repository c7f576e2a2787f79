"""Run a controller against an in-process World (fast behaviour tests of examples)."""

from __future__ import annotations

from typing import Any

from common.controller import Controller, ControllerLoop, Khepera, KheperaState, RobotCommand
from common.controller.actuators import apply_command
from common.sim2d.world import World
from common.world import packing
from common.world.remote_robot import agent_command, state_from_sample


class WorldLink:
    """A RobotLink on one agent of a World, applying commands like the engine does."""

    def __init__(self, world: World, agent: str) -> None:
        self.world = world
        self.agent = agent

    def latest(self) -> KheperaState:
        return state_from_sample(packing.sample(self.world, self.world.agent_slot(self.agent)))

    def send(self, command: RobotCommand) -> None:
        # Through the wire's form, as the engine receives it, and the engine's one mapping.
        cmd = agent_command(self.agent, command)
        apply_command(cmd, self.world.actuators(self.world.agent_slot(self.agent)))


def run_in_world(
    controller: Controller, world: World, agent: str, seconds: float, each: Any = None
) -> WorldLink:
    """Run ``controller`` for ``seconds`` of simulated time, stepping the world between calls."""
    link = WorldLink(world, agent)
    robot = Khepera(link)
    ticks = max(1, round(controller.period / world.tick_s))
    controller.initialize(robot)
    t = 0.0
    while t < seconds:
        controller.do_work(robot)
        for _ in range(ticks):
            world.step()
        t += ticks * world.tick_s
        if each is not None:
            each(world)
    controller.cleanup(robot)
    return link


__all__ = ["ControllerLoop", "WorldLink", "run_in_world"]
