"""The Class folder of an arena's panel: a course's teachers see every student, live.

Shown only to the teachers of a course (the grader answers a student's
:class:`~common.messages.ClassQuery` with no course, and refuses one that
names a course). One table per course taught (viewers/web/class_table.py):
each student's latest submission, its status and place in the grading queue,
the score, how the last failure ended, and their run on this arena if one is
running (robot, time left). It is read again when the grader says a
submission of the course changed (``GradingChanged``) and drawn again when the
arena's robots change, with no click.

From a student's row: **Watch their robot** shows the arena with the view following their
robot; **Take over their robot** pauses their controller (the context's TakeOver, as the
robot panel's button); the teacher then drives by keyboard in the driving box
or the world view (drive_keys.py: arrow keys or WASD, released keys or lost
focus stop the robot, and so does a page gone quiet for 0.6 s) or with the
robot panel's buttons; **Hand their robot back** gives the robot back. The student's page
says each step (the robot panel's status line), and the slot's recording
keeps them among its events.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import viser

from common.messages import ClassTable, GradingChanged
from viewers.web.adapters import LabConnection, LabError
from viewers.web.class_table import KeyHold, format_class, live_runs, students
from viewers.web.drive_keys import DEADMAN_S, drive_html
from viewers.web.inputs import on_click, set_value
from viewers.web.robot_panel import RobotPanel
from viewers.web.text import escape_md

log = logging.getLogger("wart.viewer.class")

NONE = "(no student)"
COALESCE_S = 0.2  # changes that come together are read once
RETRY_S = 15.0  # the grader did not answer (not started yet, restarting): ask again then


class ClassPanel:
    def __init__(
        self,
        client: viser.ClientHandle,
        connection: LabConnection,
        ctx: str,
        robots: RobotPanel,
        *,
        show_arena: Callable[[], None],
    ) -> None:
        self.connection = connection
        self.ctx = ctx
        self.robots = robots
        self._show_arena = show_arena
        self._tables: list[ClassTable] = []
        self._courses: set[str] = set()
        self._lock = threading.Lock()
        self._dirty = threading.Event()
        self._closed = threading.Event()
        self._driving: str | None = None  # the robot I took over from here
        self._keys = KeyHold(DEADMAN_S)  # the directions held in the page, and its deadman
        self._retry_at: float | None = None
        gui = client.gui
        with gui.add_folder("Class", expand_by_default=True, visible=False) as self.folder:
            self.table = gui.add_markdown("")
            self.student = gui.add_dropdown("Student", (NONE,))
            self.watch_button = gui.add_button("Watch their robot", icon=viser.Icon.EYE)
            self.take_button = gui.add_button("Take over their robot", color="orange")
            self.give_button = gui.add_button("Hand their robot back")
            self.keys = gui.add_text("Drive keys", "")
            self.drive_box = gui.add_html(drive_html(self.keys))
            self.status = gui.add_markdown("")
        on_click(self.watch_button, self.watch)
        on_click(self.take_button, self.take_over)
        on_click(self.give_button, self.hand_back)
        self.keys.on_update(lambda _: self._keys_changed(self.keys.value))
        robots.on_rows.append(self.render)
        try:
            self._unwatch = connection.courses.watch_grading(self.on_change)
        except LabError as exc:
            self._unwatch = lambda: None
            log.info("the class is not updated live: %s", exc)
        self._thread = threading.Thread(target=self._loop, name="class-panel", daemon=True)
        self._thread.start()
        self._dirty.set()  # the first read: does this user teach a course?

    def close(self) -> None:
        self._closed.set()
        self._dirty.set()
        self._unwatch()
        if self.render in self.robots.on_rows:
            self.robots.on_rows.remove(self.render)
        self._stop_driving()

    # -- live

    def on_change(self, change: GradingChanged) -> None:
        """The grader's word that a submission changed (a Zenoh thread): read again soon."""
        with self._lock:
            known = self._courses
        if change.course in known:
            self._dirty.set()

    def _loop(self) -> None:
        while not self._closed.is_set():
            if self._dirty.wait(DEADMAN_S / 3):
                time.sleep(COALESCE_S)
                self._dirty.clear()
                if self._closed.is_set():
                    return
                self.refresh()
            elif self._retry_at is not None and time.monotonic() >= self._retry_at:
                self._retry_at = None
                self._dirty.set()
            self._deadman()

    def refresh(self) -> list[ClassTable]:
        try:
            tables = self.connection.courses.class_tables()
        except LabError as exc:
            log.debug("class of %s: %s", self.connection.user, exc)  # asked again later
            self._retry_at = time.monotonic() + RETRY_S
            return self._tables
        with self._lock:
            self._tables = tables
            self._courses = {t.course for t in tables}
        if self.folder.visible != bool(tables):
            self.folder.visible = bool(tables)
        self.render()
        return tables

    def render(self) -> None:
        """Draw the tables with the arena's runs as last read (no network)."""
        if not self._tables:
            return
        runs = live_runs(self.robots.rows)
        content = format_class(self._tables, runs)
        if self.table.content != content:
            self.table.content = content
        options = (NONE, *students(self._tables))
        if tuple(self.student.options) != options:
            keep = self.student.value
            self.student.options = options
            set_value(self.student, keep if keep in options else NONE)

    def say(self, text: str, *, bad: bool = False) -> None:
        self.status.content = ("**Not done:** " if bad else "") + escape_md(text)

    # -- a student's row

    def _robot_of_student(self) -> tuple[str, str] | None:
        user = self.student.value
        if user == NONE or user not in self.student.options:
            self.say("Choose a student first.", bad=True)
            return None
        self.robots.refresh_agents()
        run = live_runs(self.robots.rows).get(user)
        if run is None:
            self.say(f"{user} runs nothing on {self.ctx} now.", bad=True)
            return None
        return user, run.agent

    def watch(self) -> str | None:
        found = self._robot_of_student()
        if found is None:
            return None
        user, agent = found
        if self.robots.view is None:
            self._show_arena()  # the arena in the view: the robot panel is bound to it
        set_value(self.robots.robot, agent)  # selects it in the view
        set_value(self.robots.follow, True)
        self.say(f"Watching {user}'s robot {agent}: the view follows it.")
        return agent

    def take_over(self) -> str | None:
        found = self._robot_of_student()
        if found is None:
            return None
        _user, agent = found
        said = self._take_or_hand_back(agent, True, f"Could not take {agent} over")
        if said is None:
            return None
        self.say(f"{said}. Drive with the arrow keys or WASD in the driving box or the view.")
        return agent

    def hand_back(self) -> str | None:
        agent = self._driving
        if agent is None:
            found = self._robot_of_student()
            if found is None:
                return None
            agent = found[1]
        self._stop_driving()
        said = self._take_or_hand_back(agent, False, f"Could not hand {agent} back")
        if said is not None:
            self.say(said)
        return said

    def _take_or_hand_back(self, agent: str, engaged: bool, failed: str) -> str | None:
        """Take ``agent`` over (``engaged``) or hand it back: what the context said, or None
        once ``failed`` and the reason are said."""
        try:
            said = self.connection.take_over(self.ctx, agent, engaged)
        except LabError as exc:
            self.say(f"{failed}: {exc}", bad=True)
            return None
        self._driving = agent if engaged else None
        self.robots.refresh_agents()
        return said

    # -- driving by keyboard

    def _keys_changed(self, value: str) -> None:
        speeds = self._keys.update(value, time.monotonic())
        if speeds is None:
            return  # a heartbeat: the same keys still held
        agent = self._driving
        if agent is None:
            if speeds != (0, 0):
                self.say("Take their robot over first, then drive.", bad=True)
            return
        try:
            self.connection.drive(self.ctx, agent, *speeds)
        except LabError as exc:
            self.say(f"Could not drive {agent}: {exc}", bad=True)

    def _deadman(self) -> None:
        """Keys held but the page silent (closed, cut off): stop the robot."""
        if self._keys.expired(time.monotonic()):
            log.info("no word from the page for %.1f s: %s stopped", DEADMAN_S, self._driving)
            self._stop_driving()

    def _stop_driving(self) -> None:
        agent = self._driving
        if agent is None:
            return
        try:
            self.connection.drive(self.ctx, agent, 0, 0)
        except LabError as exc:
            log.info("stopping %s: %s", agent, exc)
