"""The robot panel of an arena tab: agents and queues, controller upload, live sensor plots.

A thin skeleton over :class:`LabConnection` (agents, request_control,
cancel_control) and :class:`WorldFeed.sensors`; phase 2 fills in the
controller's output and the queue's live updates from the agent context.
"""

from __future__ import annotations

import logging
from collections import deque
from pathlib import PurePath

import numpy as np
import viser
import viser.uplot

from viewers.web.adapters import (
    CONTROLLER_SUFFIXES,
    MAX_CONTROLLER_BYTES,
    AgentStatus,
    LabConnection,
    LabError,
    WorldFeed,
)
from viewers.web.text import escape_md
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.robots")

MAX_ROWS = 20  # robots listed in the table
MAX_CHOICES = 200  # robots in the dropdown
PLOT_POINTS = 60  # 12 s at the pump's 5 Hz slow tick
NONE = "(none)"


def check_controller(filename: str, content: bytes) -> str | None:
    """Why an uploaded controller is refused (None: it may be queued). Never runs it."""
    name = PurePath(filename).name
    if PurePath(name).suffix not in CONTROLLER_SUFFIXES:
        return f"{name or 'the file'} is not a Python file (.py)."
    if not content:
        return f"{name} is empty."
    if len(content) > MAX_CONTROLLER_BYTES:
        return f"{name} is larger than {MAX_CONTROLLER_BYTES // 1024} KiB."
    try:
        source = content.decode("utf-8")
    except UnicodeDecodeError:
        return f"{name} is not UTF-8 text."
    try:
        compile(source, name, "exec", dont_inherit=True)  # a syntax check; nothing runs
    except SyntaxError as exc:
        return f"{name} has a syntax error on line {exc.lineno}: {exc.msg}"
    return None


def format_agents(rows: list[AgentStatus]) -> str:
    if not rows:
        return "_No robots in this arena._"
    lines = ["| robot | driven by | waiting | me | ETA |", "| --- | --- | --- | --- | --- |"]
    for r in rows[:MAX_ROWS]:
        mine = (
            "-" if r.my_position is None else ("now" if r.my_position == 0 else f"#{r.my_position}")
        )
        eta = "-" if r.eta_s is None else f"{r.eta_s:.0f} s"
        holder = escape_md(r.holder) if r.holder else "-"
        lines.append(f"| {escape_md(r.agent)} | {holder} | {r.queue} | {mine} | {eta} |")
    if len(rows) > MAX_ROWS:
        lines.append(f"\n_and {len(rows) - MAX_ROWS} more: click a robot in the view._")
    return "\n".join(lines)


class RobotPanel:
    def __init__(self, client: viser.ClientHandle, connection: LabConnection, ctx: str) -> None:
        self.client = client
        self.connection = connection
        self.ctx = ctx
        self.view: WorldView | None = None
        self.feed: WorldFeed | None = None
        self._ir: deque[np.ndarray] = deque(maxlen=PLOT_POINTS)
        self._ambient: deque[np.ndarray] = deque(maxlen=PLOT_POINTS)
        self._t: deque[float] = deque(maxlen=PLOT_POINTS)
        gui = client.gui
        with gui.add_folder("Robots"):
            self.agents_md = gui.add_markdown("")
            self.robot = gui.add_dropdown("Robot", (NONE,))
            self.upload = gui.add_upload_button(
                "Upload controller (.py)", mime_type="text/x-python", icon=viser.Icon.UPLOAD
            )
            self.cancel = gui.add_button("Cancel my request")
            self.notice = gui.add_markdown("", visible=False)
            self.selected_md = gui.add_markdown("_Click a robot in the view to select it._")
            self.rays = gui.add_checkbox("Show IR rays", False)
            empty = (np.zeros(0), *[np.zeros(0)] * 8)
            series = (
                viser.uplot.Series(label="t"),
                *[viser.uplot.Series(label=f"{i}", stroke=_colour(i), width=1) for i in range(8)],
            )
            self.ir_plot = gui.add_uplot(empty, series, title="IR proximity", aspect=2.0)
            self.ambient_plot = gui.add_uplot(empty, series, title="Ambient light", aspect=2.0)
        self.upload.on_upload(lambda _: self._uploaded())
        self.cancel.on_click(lambda _: self._cancel())
        self.robot.on_update(lambda _: self._robot_chosen())
        self.rays.on_update(lambda _: self._rays_toggled())
        self.refresh_agents()

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def refresh_agents(self) -> None:
        try:
            rows = self.connection.agents(self.ctx)
        except LabError as exc:
            self.say_notice(f"Could not read the robots: {exc}")
            return
        self.agents_md.content = format_agents(rows)
        # A dropdown of a swarm's 1,000 names is no use: past that, click robots instead.
        # NONE stays first, so a new list never selects a robot by itself.
        names = (NONE, *(r.agent for r in rows[:MAX_CHOICES]))
        if tuple(self.robot.options) != names:
            self.robot.options = names

    # -- the world view

    def bind(self, view: WorldView, feed: WorldFeed) -> None:
        self.view, self.feed = view, feed
        view.on_select.append(self._selected)
        view.slow_hooks.append(self._sample)
        view.show_rays = self.rays.value
        self.refresh_agents()  # an arena's robots are known once its world is shown

    def unbind(self) -> None:
        view = self.view
        if view is not None:
            if self._selected in view.on_select:
                view.on_select.remove(self._selected)
            if self._sample in view.slow_hooks:
                view.slow_hooks.remove(self._sample)
        self.view = self.feed = None

    def _selected(self, index: int | None) -> None:
        view = self.view
        name = view.selected_name if view else None
        self._ir.clear()
        self._ambient.clear()
        self._t.clear()
        self.selected_md.content = (
            f"Selected: **{escape_md(name)}**" if name else "_Click a robot to select it._"
        )
        if name and name in self.robot.options and self.robot.value != name:
            self.robot.value = name

    def _robot_chosen(self) -> None:
        view = self.view
        if view is None or self.robot.value not in view.robot_names:
            return
        index = view.robot_names.index(self.robot.value)
        if index != view.selected:
            view.select(index)

    def _rays_toggled(self) -> None:
        if self.view is not None:
            self.view.show_rays = self.rays.value

    def _sample(self) -> None:
        """Called at about 5 Hz by the pump: append the selected robot's sensors, replot."""
        view, feed = self.view, self.feed
        name = view.selected_name if view else None
        if feed is None or name is None:
            return
        sample = feed.sensors(name)
        if sample is None:
            return
        self._t.append(sample.t)
        self._ir.append(sample.ir)
        self._ambient.append(sample.ambient)
        t = np.asarray(self._t, np.float64)
        ir = np.asarray(self._ir, np.float64).T
        ambient = np.asarray(self._ambient, np.float64).T
        self.ir_plot.data = (t, *ir)
        self.ambient_plot.data = (t, *ambient)

    # -- controllers

    def _uploaded(self) -> None:
        uploaded = self.upload.value
        problem = check_controller(uploaded.name, uploaded.content)
        if problem:
            self.say_notice(f"Not queued: {problem}")
            return
        agent = self.robot.value
        if agent == NONE:
            self.say_notice("Choose a robot first.")
            return
        try:
            self.connection.request_control(self.ctx, agent, uploaded.name, uploaded.content)
        except LabError as exc:
            self.say_notice(f"Not queued: {exc}")
            return
        self.say_notice(f"{PurePath(uploaded.name).name} is queued for {agent}.")
        self.refresh_agents()

    def _cancel(self) -> None:
        agent = self.robot.value
        try:
            self.connection.cancel_control(self.ctx, agent)
        except LabError as exc:
            self.say_notice(f"Could not cancel: {exc}")
            return
        self.refresh_agents()


def _colour(i: int) -> str:
    return ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45"][
        i % 8
    ]
