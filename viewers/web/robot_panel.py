"""The robot panel of an arena tab: agents and queues, uploads, output, settings, plots.

Over :class:`LabConnection` (agents, request_control, cancel_control,
arena_settings, set_slot, stop_agent, set_enabled) and
:class:`WorldFeed.sensors`. The table shows every robot with who drives it,
how many wait, my place and when my slot should start; an upload is checked
in the page (the same pre-check the agent context runs) before it is sent;
the running controllers' prints arrive live. "Dry run (.py)" runs a file a few
simulated seconds in a private copy of the arena and shows "will run" /
"will NOT run: ..." without queueing it. The owner of the context (or
someone with 'kick' there) also gets its settings: slot length, stop the
running controller, disable or enable a robot or the whole context, and the
emergency stop (every robot, at once, until released). The agent context
re-checks every right: the page only hides what would be refused.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot

from common.acl import account_in_words
from viewers.web.adapters import (
    AgentStatus,
    ArenaSettings,
    LabConnection,
    LabError,
    OutputEvent,
    RequestEvent,
)
from viewers.web.ghost import Ghost
from viewers.web.inputs import set_value
from viewers.web.live_agents import check_upload
from viewers.web.text import escape_md, output_html, printed
from viewers.web.world_feed import WorldFeed
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.robots")

MAX_ROWS = 20  # robots listed in the table
MAX_CHOICES = 200  # robots in the dropdown
PLOT_POINTS = 60  # 12 s at the pump's 5 Hz slow tick
OUTPUT_LINES = 40  # older output scrolls away
NOTHING_PRINTED = "Nothing printed yet."
TABLE_EVERY_S = 1.0  # the ETAs count down between the context's events
NONE = "(none)"
ALL = "(all robots)"
# The take-over's drive buttons: wheel speeds (Khepera units), held until the next press.
DRIVE_SPEEDS = {
    "Forward": (10, 10),
    "Reverse": (-10, -10),
    "Turn left": (-5, 5),
    "Turn right": (5, -5),
    "Stop driving": (0, 0),
}
STATUS_WORDS = {
    "queued": "is queued",
    "running": "is running",
    "finished": "finished",
    "cancelled": "was cancelled",
    "refused": "was refused",
    "taken": "is paused: a teacher took the robot over",
    "handed_back": "drives again: the robot was handed back",
}


def check_controller(filename: str, content: bytes) -> str | None:
    """Why an uploaded controller is refused (None: it may be queued). Never runs it."""
    return check_upload(filename, content)[1]


def format_agents(rows: list[AgentStatus], settings: ArenaSettings | None = None) -> str:
    if not rows:
        return "_No robots in this arena._"
    lines = []
    if settings is not None and settings.slot_seconds > 0:
        state = "" if settings.enabled else " · **remote control is off**"
        lines.append(f"Slots of {settings.slot_seconds:g} s{state}\n")
    if settings is not None and settings.estop:
        lines.append(f"**{escape_md(settings.estop)}**: every robot is held until it is released\n")
    lines += ["| robot | driven by | waiting | me | ETA |", "| --- | --- | --- | --- | --- |"]
    for r in rows[:MAX_ROWS]:
        mine = (
            "-" if r.my_position is None else ("now" if r.my_position == 0 else f"#{r.my_position}")
        )
        eta = "-" if r.eta_s is None else f"{r.eta_s:.0f} s"
        holder = escape_md(account_in_words(r.holder)) if r.holder else "-"
        if r.holder and r.slot_left_s is not None:
            holder += f" ({r.slot_left_s:.0f} s left)"
        if r.taken_by:
            holder += f", **taken over by {escape_md(r.taken_by)}** (paused)"
        name = escape_md(r.agent)
        if not r.online:
            name += " (offline)"
        elif not r.enabled and settings is not None and settings.slot_seconds > 0:
            name += " (disabled)"
        waiting = str(r.queue)
        if r.waiting and settings is not None and settings.can_manage:  # the teacher's view
            waiting += ": " + ", ".join(escape_md(u) for u in r.waiting[:5])
            waiting += " ..." if len(r.waiting) > 5 else ""
        lines.append(f"| {name} | {holder} | {waiting} | {mine} | {eta} |")
    if len(rows) > MAX_ROWS:
        lines.append(f"\n_and {len(rows) - MAX_ROWS} more: click a robot in the view._")
    return "\n".join(lines)


@dataclass(frozen=True)
class RobotPanelMemory:
    """The panel's choices and the output so far, kept while the page reloads."""

    robot: str
    output: tuple[str, ...]
    rays: bool
    follow: bool


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
        self._rows: list[AgentStatus] = []
        self._settings: ArenaSettings | None = None
        self._output: deque[str] = deque(maxlen=OUTPUT_LINES)
        self._table_at = 0.0
        self.on_rows: list[Callable[[], None]] = []  # called when the robots were re-read
        gui = client.gui
        with gui.add_folder("Robots"):
            # The host's emergency stop: first, and outside the folded settings (shown
            # to the owner or those with 'kick' there only).
            self.estop = gui.add_button("Emergency stop (every robot)", color="red", visible=False)
            self.release = gui.add_button("Release the emergency stop", visible=False)
            self.agents_md = gui.add_markdown("")
            self.robot = gui.add_dropdown("Robot", (NONE,))
            # Before the upload button: tests find the upload's input as the last one.
            self.dry_run = gui.add_upload_button("Dry run (.py)", mime_type="text/x-python")
            self.dry_run_md = gui.add_markdown("", visible=False)
            self.upload = gui.add_upload_button(
                "Upload controller (.py)", mime_type="text/x-python", icon=viser.Icon.UPLOAD
            )
            self.cancel = gui.add_button("Cancel my request")
            self.notice = gui.add_markdown("", visible=False)
            with gui.add_folder("Controller output"):
                # HTML, not markdown: a print is shown exactly as printed.
                self.output_md = gui.add_html(output_html([], NOTHING_PRINTED))
            # Instructor controls: shown to the context's owner or those with 'kick' there.
            with gui.add_folder("Arena settings", expand_by_default=False) as self.manage:
                self.slot = gui.add_number("Slot length (s)", 60.0, min=1.0, max=3600.0, step=1.0)
                self.set_slot = gui.add_button("Set slot length")
                self.stop = gui.add_button("Stop the running controller", color="red")
                self.disable = gui.add_button("Disable remote control")
                self.enable = gui.add_button("Enable remote control")
                self.which = gui.add_dropdown("Applies to", (ALL, "the chosen robot"))
            self.manage.visible = False
            # A teacher's take-over of the chosen robot (the same managers): the running
            # controller paused, the robot driven from here, handed back.
            with gui.add_folder("Take over (teacher)") as self.takeover:
                self.take = gui.add_button("Take over the chosen robot", color="orange")
                self.give_back = gui.add_button("Hand back")
                self.drive_buttons = {label: gui.add_button(label) for label in DRIVE_SPEEDS}
            self.takeover.visible = False
            self.selected_md = gui.add_markdown("_Click a robot in the view to select it._")
            self.rays = gui.add_checkbox(
                "Show IR rays",
                False,
                hint="The selected robot's IR readings as rays: longer and redder when higher",
            )
            self.follow = gui.add_checkbox(
                "Follow the selected robot",
                False,
                hint="Keep the selected robot in the middle of the view (zoom stays yours)",
            )
            # The twin's prediction over a live real run (its checkbox and legend).
            self.ghost = Ghost(gui, lambda robot: connection.twin(ctx, robot), self.driven)
            empty = (np.zeros(0), *[np.zeros(0)] * 8)
            series = (
                viser.uplot.Series(label="t"),
                *[viser.uplot.Series(label=f"{i}", stroke=_colour(i), width=1) for i in range(8)],
            )
            self.ir_plot = gui.add_uplot(empty, series, title="IR proximity", aspect=2.0)
            self.ambient_plot = gui.add_uplot(empty, series, title="Ambient light", aspect=2.0)
        self.upload.on_upload(lambda _: self._uploaded())
        self.dry_run.on_upload(lambda _: self._dry_run())
        self.estop.on_click(lambda _: self._emergency_stop(True))
        self.release.on_click(lambda _: self._emergency_stop(False))
        self.cancel.on_click(lambda _: self._cancel())
        self.robot.on_update(lambda _: self._robot_chosen())
        self.rays.on_update(lambda _: self._rays_toggled())
        self.follow.on_update(lambda _: self._follow_toggled())
        self.set_slot.on_click(lambda _: self._set_slot())
        self.stop.on_click(lambda _: self._stop())
        self.disable.on_click(lambda _: self._enable(False))
        self.enable.on_click(lambda _: self._enable(True))
        self.take.on_click(lambda _: self._take_over(True))
        self.give_back.on_click(lambda _: self._take_over(False))
        for label, button in self.drive_buttons.items():
            button.on_click(self._drive_on_click(*DRIVE_SPEEDS[label]))
        self.refresh_agents()

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    # -- surviving a reload

    def memory(self) -> RobotPanelMemory:
        return RobotPanelMemory(
            robot=self.robot.value,
            output=tuple(self._output),
            rays=self.rays.value,
            follow=self.follow.value,
        )

    def put_back(self, kept: RobotPanelMemory) -> None:
        self._output.extend(kept.output)
        self.output_md.content = output_html(self._output, NOTHING_PRINTED)
        set_value(self.rays, kept.rays)
        set_value(self.follow, kept.follow)
        if kept.robot in self.robot.options:
            set_value(self.robot, kept.robot)

    def refresh_agents(self) -> None:
        """Re-read the queues (cheap: the connection keeps the context's newest state)."""
        try:
            rows = self.connection.agents(self.ctx)
            settings = self.connection.arena_settings(self.ctx)
        except LabError as exc:
            self.say_notice(f"Could not read the robots: {exc}")
            return
        self._rows, self._settings = rows, settings
        self._table_at = time.monotonic()
        content = format_agents(rows, settings)
        if self.agents_md.content != content:
            self.agents_md.content = content
        if self.takeover.visible != settings.can_manage:
            self.takeover.visible = settings.can_manage
        if self.manage.visible != settings.can_manage:
            self.manage.visible = settings.can_manage
            if settings.can_manage:
                set_value(self.slot, settings.slot_seconds)
        stop_shown = settings.can_manage and not settings.estop
        if self.estop.visible != stop_shown:
            self.estop.visible = stop_shown
        release_shown = settings.can_manage and bool(settings.estop)
        if self.release.visible != release_shown:
            self.release.visible = release_shown
        # A dropdown of a swarm's 1,000 names is no use: past that, click robots instead.
        # NONE stays first, so a new list never selects a robot by itself.
        names = (NONE, *(r.agent for r in rows[:MAX_CHOICES]))
        if tuple(self.robot.options) != names:
            self.robot.options = names
        for hook in self.on_rows:
            hook()

    @property
    def rows(self) -> list[AgentStatus]:
        """The arena's robots as last read (no network)."""
        return list(self._rows)

    def driven(self, agent: str) -> bool:
        """Does someone's controller hold ``agent`` now (as last read)?"""
        return any(r.agent == agent and r.holder is not None for r in self._rows)

    # -- the agent context's news (the connection's thread)

    def on_request(self, event: RequestEvent) -> None:
        mine = event.user == self.connection.user
        who = "your" if mine else f"{event.user}'s"
        why = f": {event.reason}" if event.reason else ""
        words = STATUS_WORDS.get(event.takeover or event.status, event.status)
        self._add_output(f"<i>{printed(f'{who} controller on {event.agent} {words}{why}')}</i>")
        if mine and event.status in ("running", "finished", "cancelled", "refused"):
            self.client.add_notification(
                title=f"{event.agent}: your controller {words}",
                body=event.reason or f"in {self.ctx}",
                auto_close_seconds=5.0,
                color="red" if event.status == "refused" else None,
            )

    def on_output(self, event: OutputEvent) -> None:
        tag = f"<b>{printed(event.agent)} {printed(event.user)}:</b>"
        for line in event.lines:
            self._add_output(f"{tag} {printed(line)}")

    def _add_output(self, line: str) -> None:
        """``line`` is HTML whose user text is escaped (:func:`printed`)."""
        self._output.append(line)
        self.output_md.content = output_html(self._output, NOTHING_PRINTED)

    # -- the world view

    def bind(self, view: WorldView, feed: WorldFeed) -> None:
        self.view, self.feed = view, feed
        view.on_select.append(self._selected)
        view.slow_hooks.append(self._sample)
        view.show_rays = self.rays.value
        view.follow = self.follow.value
        self.ghost.bind(view)
        self.refresh_agents()  # an arena's robots are known once its world is shown
        # A robot selected before this panel was bound (a click while a busy page still
        # built it) is shown as selected, not lost until the next click.
        self._selected(view.selected)

    def unbind(self) -> None:
        view = self.view
        if view is not None:
            if self._selected in view.on_select:
                view.on_select.remove(self._selected)
            if self._sample in view.slow_hooks:
                view.slow_hooks.remove(self._sample)
            view.follow = False  # the next panel bound says whether it follows
        self.ghost.unbind()
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
            set_value(self.robot, name)

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

    def _follow_toggled(self) -> None:
        if self.view is not None:
            self.view.follow = self.follow.value

    def _sample(self) -> None:
        """Called at about 5 Hz by the pump: append the selected robot's sensors, replot."""
        if time.monotonic() - self._table_at >= TABLE_EVERY_S:
            self.refresh_agents()  # ETAs and slot time count down
        view, feed = self.view, self.feed
        name = view.selected_name if view else None
        if feed is None or name is None:
            return
        sample = feed.sensors(name)
        if sample is None:
            return
        if self._t and sample.t < self._t[-1]:  # a replay scrubbed back: start the plot again
            self._t.clear()
            self._ir.clear()
            self._ambient.clear()
        self._t.append(sample.t)
        self._ir.append(sample.ir)
        self._ambient.append(sample.ambient)
        t = np.asarray(self._t, np.float64)
        ir = np.asarray(self._ir, np.float64).T
        ambient = np.asarray(self._ambient, np.float64).T
        self.ir_plot.data = (t, *ir)
        self.ambient_plot.data = (t, *ambient)

    # -- controllers

    def _chosen(self) -> str | None:
        agent = self.robot.value
        if agent == NONE or agent not in self.robot.options:
            self.say_notice("Choose a robot first (the list, or click one in the view).")
            return None
        return agent

    def _uploaded(self) -> None:
        uploaded = self.upload.value
        name, problem = check_upload(uploaded.name, uploaded.content)
        if problem:
            self.say_notice(f"Not queued: {problem}")
            return
        agent = self._chosen()
        if agent is None:
            return
        try:
            queued = self.connection.request_control(self.ctx, agent, name, uploaded.content)
        except LabError as exc:
            self.say_notice(f"Not queued: {exc}")
            return
        if queued.position == 0 or (queued.eta_s is not None and queued.eta_s < 1.0):
            where = "it starts now"
        else:
            eta = "" if queued.eta_s is None else f", starting in about {queued.eta_s:.0f} s"
            where = f"you are #{queued.position} in the queue{eta}"
        self.say_notice(f"{name} is queued for {agent}: {where}.")
        self.refresh_agents()

    def _dry_run(self) -> None:
        uploaded = self.dry_run.value
        name, problem = check_upload(uploaded.name, uploaded.content)
        self.dry_run_md.visible = True
        if problem:
            self.dry_run_md.content = f"**Dry run: {escape_md(problem)}**"
            return
        agent = self._chosen()
        if agent is None:
            self.dry_run_md.visible = False
            return
        self.dry_run_md.content = f"_Dry run of {escape_md(name)} on {escape_md(agent)}..._"
        try:
            result = self.connection.dry_run(self.ctx, agent, name, uploaded.content)
        except LabError as exc:
            self.dry_run_md.content = f"**Dry run: {escape_md(str(exc))}**"
            return
        details = "".join(f"  \n{escape_md(line)}" for line in result.details)
        self.dry_run_md.content = (
            f"Dry run of {escape_md(name)} on {escape_md(agent)}: "
            f"**{escape_md(result.verdict)}**{details}"
        )

    def _cancel(self) -> None:
        mine = [r.agent for r in self._rows if r.my_request]
        # With one request of mine there is nothing to choose: cancel it.
        agent = mine[0] if len(mine) == 1 and self.robot.value not in mine else self._chosen()
        if agent is None:
            return
        try:
            detail = self.connection.cancel_control(self.ctx, agent)
        except LabError as exc:
            self.say_notice(f"Could not cancel: {exc}")
            return
        self.say_notice(detail or f"Your request on {agent} is cancelled.")
        self.refresh_agents()

    # -- the owner's settings

    def _manage(self, what: str, act: Callable[[], str]) -> None:
        try:
            detail = act()
        except LabError as exc:
            self.say_notice(f"Could not {what}: {exc}")
            return
        self.say_notice(detail)
        self.refresh_agents()

    def _emergency_stop(self, engaged: bool) -> None:
        what = "stop every robot" if engaged else "release the emergency stop"
        self._manage(what, lambda: self.connection.emergency_stop(self.ctx, engaged))

    def _set_slot(self) -> None:
        seconds = self.slot.value
        if not isinstance(seconds, int | float) or not 1.0 <= float(seconds) <= 3600.0:
            self.say_notice("A slot lasts between 1 and 3600 seconds.")
            return
        self._manage(
            "change the slot length", lambda: self.connection.set_slot(self.ctx, float(seconds))
        )

    def _stop(self) -> None:
        agent = self._chosen()
        if agent is not None:
            self._manage("stop it", lambda: self.connection.stop_agent(self.ctx, agent))

    def _take_over(self, take: bool) -> None:
        agent = self._chosen()
        if agent is not None:
            what = f"take {agent} over" if take else f"hand {agent} back"
            self._manage(what, lambda: self.connection.take_over(self.ctx, agent, take))

    def _drive_on_click(self, left: int, right: int) -> Callable[[object], None]:
        return lambda _: self._drive(left, right)

    def _drive(self, left: int, right: int) -> None:
        agent = self._chosen()
        if agent is None:
            return
        try:
            self.connection.drive(self.ctx, agent, left, right)
        except LabError as exc:
            self.say_notice(f"Could not drive {agent}: {exc}")

    def _enable(self, enabled: bool) -> None:
        agent: str | None = None
        if self.which.value != ALL:
            agent = self._chosen()
            if agent is None:
                return
        what = "enable" if enabled else "disable"
        self._manage(
            f"{what} remote control",
            lambda: self.connection.set_enabled(self.ctx, enabled, agent),
        )


def _colour(i: int) -> str:
    return ["#e6194b", "#3cb44b", "#4363d8", "#f58231", "#911eb4", "#42d4f4", "#f032e6", "#bfef45"][
        i % 8
    ]
