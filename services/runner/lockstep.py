"""A controller in the sandbox stepped with a private world: the dry run's and the episode's loop.

Each tick the world's state goes to the controller, its answer (the commands
it sent while handling that state) comes back, and only then does the caller
step the world: a slow controller slows the simulation, never the other way
round. The run ends when the ticks are done, the child exits (its reason is
the sandbox's), or the wall-clock limit passes (``timed_out``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from common.controller import (
    ARM_UP,
    LIGHT_SENSORS,
    PROXIMITY_SENSORS,
    KheperaState,
    RobotCommand,
)
from common.sim2d import world_discs
from common.sim2d.collision import CAT_OBJECT, CAT_OBSTACLE, CAT_ROBOT
from common.sim2d.parts import parts_of
from common.sim2d.world import World
from services.runner.sandbox import Sandbox, SandboxLimits


def lockstep_limits(base: SandboxLimits | None, wall_s: float) -> SandboxLimits:
    """``base``'s limits for a lockstep run: CPU within the wall-clock limit, and no
    per-second command budget (it protects a real robot's link; here nothing but
    this world listens, and states come far faster than real time)."""
    base = base or SandboxLimits()
    return SandboxLimits(
        cpu_seconds=min(base.cpu_seconds, int(wall_s) + 1),
        memory_bytes=base.memory_bytes,
        processes=base.processes,
        open_files=base.open_files,
        file_size_bytes=base.file_size_bytes,
        output_lines_per_second=base.output_lines_per_second,
        commands_per_second=100_000,
        output_bytes_per_second=base.output_bytes_per_second,
        cpu_share=base.cpu_share,
    )


class Lockstep:
    """``source`` on robot ``slot`` of ``world``, one tick per answer (see the module)."""

    def __init__(
        self,
        source: bytes,
        filename: str,
        world: World,
        slot: int,
        *,
        wall_s: float,
        limits: SandboxLimits | None = None,
        max_output: int = 50,
        max_line: int = 1000,
    ) -> None:
        self.world, self.slot, self.wall_s = world, slot, wall_s
        self.output: list[str] = []
        self.steps = 0
        self.timed_out = False
        self.ready: float | None = None  # when the child had loaded the controller
        self._commands: list[RobotCommand] = []
        self._lock = threading.Lock()
        self._answered = threading.Event()
        self._max_output, self._max_line = max_output, max_line
        self.sandbox = Sandbox(
            source,
            filename=filename,
            limits=lockstep_limits(limits, wall_s),
            on_command=self._on_command,
            on_output=self._on_output,
            on_step=self._answered.set,
        )

    def _on_command(self, command: RobotCommand) -> None:
        with self._lock:
            self._commands.append(command)

    def _on_output(self, line: str) -> None:
        if self.ready is None and line.startswith("[runner] controller "):
            self.ready = time.monotonic()  # loaded (the sandbox says so on its Ready)
        with self._lock:
            if len(self.output) < self._max_output and not line.startswith("[runner] controller"):
                self.output.append(line[: self._max_line])

    def ticks(self, count: int) -> Iterator[list[RobotCommand]]:
        """Start the child; yield each tick's commands once it answered (the caller applies
        them and steps the world); stop early when it exits or the wall clock runs out."""
        deadline = time.monotonic() + self.wall_s
        self.sandbox.start(self.wall_s)
        for _ in range(count):
            self._answered.clear()
            if not self.sandbox.send_state(state_of(self.world, self.slot)):
                return  # the child is gone: the reason is its exit
            while not self._answered.wait(0.05):
                if time.monotonic() >= deadline:
                    self.timed_out = True
                    return
                if self.sandbox.wait(0):
                    return
            self.steps += 1
            with self._lock:
                mine, self._commands = self._commands, []
            yield mine

    # -- one tick at a time, for a caller stepping several controllers in one world (heat.py)

    def offer(self) -> bool:
        """Send this tick's state; False if the child is gone."""
        self._answered.clear()
        return self.sandbox.send_state(state_of(self.world, self.slot))

    def answer(self, deadline: float, tick_limit: float | None = None) -> bool:
        """Wait for the child's answer to the state offered; False if it exited or the wall
        clock ran out (``timed_out``) first: ``deadline``, or ``tick_limit`` s of waiting
        once the controller has loaded. Its commands are then :meth:`take`'s."""
        began = time.monotonic()
        while not self._answered.wait(0.05):
            now = time.monotonic()
            loaded = self.ready
            if tick_limit is not None and loaded is not None:
                late = now - max(began, loaded) >= tick_limit
            else:
                late = False
            if now >= deadline or late:
                self.timed_out = True
                return False
            if self.sandbox.wait(0):
                return False
        self.steps += 1
        return True

    def take(self) -> list[RobotCommand]:
        with self._lock:
            mine, self._commands = self._commands, []
        return mine

    def stop(self, reason: str) -> None:
        self.sandbox.stop(grace=0.3, reason=reason)


def state_of(world: World, slot: int) -> KheperaState:
    """What the controller sees of its robot this tick (as the sandbox's child reads it)."""
    agent = world.agents[slot]
    spec = agent.spec

    def fit(values: list[int], count: int, fill: int) -> list[int]:
        return ([max(0, min(1023, int(v))) for v in values] + [fill] * count)[:count]

    prox = world.proximity[slot].tolist()[: len(spec.proximity.poses)]
    amb = world.ambient[slot].tolist()[: len(spec.ambient.poses)]
    leds = [*world.leds[slot].tolist()[: spec.leds], 0, 0]
    speeds = [max(-127, min(127, int(v))) for v in world.cmd[slot].tolist()]
    counters = [int(c) for c in world.counters[slot].tolist()]
    state = KheperaState(
        time=world.sim_time,
        speeds=(speeds[0], speeds[1]),
        counters=(counters[0], counters[1]),
        proximity=tuple(fit(prox, PROXIMITY_SENSORS, 0)),
        ambient=tuple(fit(amb, LIGHT_SENSORS, 500)),
        leds=(bool(leds[0]), bool(leds[1])),
        arm=ARM_UP,
        parts={k: tuple(int(x) for x in v) for k, v in parts_of(world, [slot])[0].items()},
    )
    if agent.has_gripper:
        state = replace(
            state,
            arm=int(np.clip(np.rint(world.arm[slot]), 0, 255)),
            gripper_closed=world.gripper_state(slot) != 0,
            object_present=int(world.presence[slot]) >= 128,
            resistivity=int(world.resistivity(slot)),
        )
    return state


class Touches:
    """What the robot's body touches after a tick: new contacts become collisions."""

    def __init__(self, world: World, slot: int) -> None:
        self.world = world
        self.agent = world.agents[slot]
        self.body = self.agent.body
        self.touching: set[tuple[str, str]] = set()
        self.names = self._names()

    def _names(self) -> dict[int, tuple[str, str]]:
        world, names = self.world, {}
        for ident, obstacle in world.obstacles.items():
            for body in [obstacle.body] if obstacle.body is not None else []:
                names[id(body)] = ("obstacle", ident)
        for obj in world.objects:
            if obj.body is not None:
                names[id(obj.body)] = ("object", obj.id)
        for agent in world.agents:
            names[id(agent.body)] = ("robot", agent.id)
        return names

    def new_contacts(self) -> list[tuple[str, str]]:
        if self.world.drive == "discs":
            # No chipmunk arbiters on that drive: the contacts are measured.
            now = world_discs.touching(self.world.state, self.world.agents.index(self.agent))
            new = sorted(now - self.touching)
            self.touching = now
            return new
        now = set()

        def seen(arbiter: Any) -> None:
            for shape in arbiter.shapes:
                if shape.body is self.body:
                    continue
                named = self.names.get(id(shape.body))
                if named is None:
                    category = shape.filter.categories
                    if category & CAT_OBSTACLE:
                        named = ("wall", "")
                    elif category & CAT_ROBOT:
                        named = ("robot", "")
                    elif category & CAT_OBJECT:
                        named = ("object", "")
                    else:
                        continue
                now.add(named)

        self.body.each_arbiter(seen)
        new = sorted(now - self.touching)
        self.touching = now
        return new
