"""The robot the editor's buttons act on ("Run on"): this arena's robots, then those of the real
arenas joined; it and the robot panel's choice (or a click in the view) follow each other."""

from __future__ import annotations

from collections.abc import Callable

import viser

from common.controller.robot import RobotApi
from viewers.web.adapters import LabConnection, LabError
from viewers.web.inputs import set_value
from viewers.web.robot_panel import NONE, RobotPanel


class RunOn:
    def __init__(
        self, gui: viser.GuiApi, connection: LabConnection, ctx: str, robots: RobotPanel
    ) -> None:
        self.connection = connection
        self.ctx = ctx
        self.robots = robots
        self.dropdown = gui.add_dropdown("Run on", (NONE,))
        self.dropdown.on_update(lambda _: self._chosen_here())
        robots.robot.on_update(lambda _: self._chosen_in_panel())
        robots.on_rows.append(self.refresh)

    def targets(self) -> list[tuple[str, str]]:
        """(context, robot) the editor can run on: this arena's, then the real arenas'."""
        here = [(self.ctx, a) for a in self.robots.robot.options if a != NONE]
        try:
            real = [r for r in self.connection.real_robots() if r[0] != self.ctx]
        except LabError:
            real = []
        return here + real

    def label(self, ctx: str, agent: str) -> str:
        return agent if ctx == self.ctx else f"{ctx}/{agent}"

    def refresh(self) -> None:
        options = (NONE, *(self.label(*t) for t in self.targets()))
        if tuple(self.dropdown.options) != options:
            keep = self.dropdown.value
            self.dropdown.options = options
            set_value(self.dropdown, keep if keep in options else NONE)

    def _chosen_here(self) -> None:
        value = self.dropdown.value
        if value in self.robots.robot.options and self.robots.robot.value != value:
            set_value(self.robots.robot, value)  # the view selects it, the panel shows it

    def _chosen_in_panel(self) -> None:
        value = self.robots.robot.value  # chosen in the robot panel, or clicked in the view
        if value != NONE and value in self.dropdown.options and self.dropdown.value != value:
            set_value(self.dropdown, value)

    def target(self) -> tuple[str, str] | None:
        value = self.dropdown.value
        return next((t for t in self.targets() if self.label(*t) == value), None)

    def here(self, say: Callable[..., None]) -> str | None:
        """The chosen robot of this arena, or None with what to do said."""
        target = self.target()
        panel = self.robots.robot.value
        if target is None and panel != NONE and panel in self.robots.robot.options:
            target = (self.ctx, panel)
        if target is None:
            say("Choose a robot first in 'Run on' (or click one in the view).", bad=True)
            return None
        ctx, agent = target
        if ctx != self.ctx:
            say(f"{agent} is a real robot in {ctx}: use 'Queue on the real robot'.", bad=True)
            return None
        return agent

    def robot_api(self) -> RobotApi | None:
        """The chosen robot's components, when its world says them (else the Khepera's API)."""
        target = self.target()
        panel = self.robots.robot.value
        agent = target[1] if target else (panel if panel in self.robots.robot.options else None)
        feed = self.robots.feed
        if agent is None or feed is None:
            return None
        try:
            known = feed.snapshot().robot_types.get(agent)
        except LabError:
            return None
        if not known or not known[1]:
            return None
        return RobotApi.of(known[0], known[1])

    def arena_is_real(self) -> bool:
        feed = self.robots.feed
        try:
            return feed is not None and feed.snapshot().real
        except LabError:
            return False
