"""A joined context's tab: chat history, members, live lines, notices, kick, leave.

An arena (agent context) tab also carries the robot panel and, for those
with edit_map, the map editor, and a button that shows its world in the view.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import viser

from common.lab_errors import NotAnswering
from viewers.web.adapters import (
    ChatEntry,
    ChatEvent,
    JoinedContext,
    LabConnection,
    LabError,
    MemberEvent,
)
from viewers.web.builder import RobotBuilder
from viewers.web.class_panel import ClassPanel
from viewers.web.course_panel import CoursePanel
from viewers.web.editor import MapEditor
from viewers.web.inputs import set_value
from viewers.web.recordings_panel import RecordingsPanel
from viewers.web.replay import ReplayFeed
from viewers.web.robot_panel import RobotPanel, RobotPanelMemory
from viewers.web.tabs import tab_title
from viewers.web.text import check_line, clock, escape_md
from viewers.web.workbench import BenchMemory, Workbench
from viewers.web.world_feed import WorldFeed
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.chat")

ARENA_KINDS = ("agent", "world")  # an agent context, or a world no context announces yet
SHOWN_LINES = 100  # older lines scroll away; the context keeps the full history
WORLD_RETRY_S = 3.0  # asking again for a world that does not answer yet


@dataclass(frozen=True)
class PanelMemory:
    """A joined context's tab as the page left it (a reload): the lab session stays joined."""

    joined: JoinedContext  # as joined, with today's members
    lines: tuple[str, ...]  # the chat lines shown
    robots: RobotPanelMemory | None
    bench: BenchMemory | None


class ChatPanel:
    def __init__(
        self,
        client: viser.ClientHandle,
        tabs: viser.GuiTabGroupHandle,
        connection: LabConnection,
        joined: JoinedContext,
        *,
        on_close: Callable[[ChatPanel], None],
        on_watch: Callable[[WorldFeed, ChatPanel], None] | None = None,
        kept: PanelMemory | None = None,
        editor: BenchMemory | None = None,
    ) -> None:
        """``kept``: the panel as a reloaded page left it; ``editor``: only the editor's
        text, put back in a panel joined anew (a restarted viewer's, handover.py)."""
        self.joined = joined
        self.client = client
        self.connection = connection
        self.ctx = joined.ctx
        self.kind = joined.kind
        self.world = joined.world
        self.members: tuple[str, ...] = joined.members
        self._on_close = on_close
        self._on_watch = on_watch
        self._lines: deque[str] = deque(maxlen=SHOWN_LINES)
        self.closed = False
        # Whether this panel's tab is in front in the page (the client keeps it from the
        # page's reports; a panel opens in front). An arena that answers late is shown
        # only then: the student who moved on to another arena meanwhile stays there.
        self.in_front = True
        self._retry_lock = threading.Lock()
        self._retrying = False
        if kept is None:
            self._lines.extend(self._format(line) for line in joined.history)
        else:
            self._lines.extend(kept.lines)
        gui = client.gui
        label = f"{self.ctx}" if self.kind not in ARENA_KINDS else f"{self.ctx} (arena)"
        self.tab_name = label
        self.tab_title = f"{label} in {tab_title(connection.address)}"
        # The panel reaches the page with its handlers: a click that comes before its
        # handler is dropped without a trace (login.py says how that was seen), and an
        # arena's panel builds its robots, workbench and editors between its first
        # button and the last handler. Nothing here waits on the lab.
        with client.atomic():
            self.tab = tabs.add_tab(label, icon=viser.Icon.MESSAGE if self.kind == "chat" else None)
            with self.tab:
                title = escape_md(joined.title or self.ctx)
                gui.add_markdown(
                    f"**{title}** · {escape_md(connection.address.label)} · owner "
                    f"{escape_md(joined.owner)}"
                )
                self.members_md = gui.add_markdown("")
                self.log_md = gui.add_markdown("")
                self.message = gui.add_text("Message", "")
                self.send = gui.add_button("Send", color="blue")
                self.notice = gui.add_markdown("", visible=False)
                self.kick_who = gui.add_dropdown(
                    "Member", self._others() or ("(nobody)",), visible=joined.can_kick
                )
                self.kick = gui.add_button("Kick", color="red", visible=joined.can_kick)
                self.robots: RobotPanel | None = None
                self.workbench: Workbench | None = None
                self.editor: MapEditor | None = None
                self.builder: RobotBuilder | None = None
                self.recordings: RecordingsPanel | None = None
                self.course: CoursePanel | None = None
                self.klass: ClassPanel | None = None
                self.view: WorldView | None = None  # the page's view, once this arena was shown
                if self.kind in ARENA_KINDS and self.world and on_watch is not None:
                    self.watch = gui.add_button("Show this arena", color="teal")
                    self.watch.on_click(lambda _: self.show_world())
                    self.robots = RobotPanel(client, connection, self.ctx)
                    if kept is not None and kept.robots is not None:
                        self.robots.put_back(kept.robots)
                    self.workbench = Workbench(
                        client, connection, self.ctx, self.robots, kept.bench if kept else editor
                    )
                    # Assignments are handed in from here: the file open in the editor above.
                    self.course = CoursePanel(
                        client,
                        connection,
                        source=self.workbench.current_file,
                        view=lambda: self.view,
                        show=self._show_replay,
                        back_to_live=self.show_world,
                    )
                    # A course's teachers only: every student, live; watch and take over.
                    self.klass = ClassPanel(
                        client, connection, self.ctx, self.robots, show_arena=self.show_world
                    )
                    # Everyone sees the editor; without edit_map it is disabled and says why.
                    self.editor = MapEditor(client, allowed="edit_map" in connection.permissions)
                    # A robot someone's controller drives is theirs: no map-editing handles on it.
                    self.editor.driven = self.robots.driven
                    self.builder = RobotBuilder(
                        client, allowed="edit_map" in connection.permissions
                    )
                    self.builder.on_saved.append(self.editor.offer_type)
                    self.recordings = RecordingsPanel(
                        client,
                        connection,
                        self.ctx,
                        view=lambda: self.view,
                        show=self._show_replay,
                        back_to_live=self.show_world,
                        owner=joined.owner == connection.user,
                    )
                self.leave = gui.add_button("Leave")
            self.send.on_click(lambda _: self.submit())
            self.kick.on_click(lambda _: self.kick_selected())
            self.leave.on_click(lambda _: self.close(leave=True))
        self._render()

    # -- rendering

    @staticmethod
    def _format(line: ChatEntry) -> str:
        return f"`{clock(line.at)}` **{escape_md(line.sender)}**: {escape_md(line.text)}"

    def _others(self) -> tuple[str, ...]:
        return tuple(m for m in self.members if m != self.connection.user)

    def _render(self) -> None:
        self.members_md.content = "Members: " + ", ".join(escape_md(m) for m in self.members)
        # Two spaces before the newline: markdown line breaks, one line per message.
        self.log_md.content = "  \n".join(self._lines) or "_No messages yet._"
        if self.kick.visible:
            self.kick_who.options = self._others() or ("(nobody)",)

    def say_notice(self, text: str) -> None:
        self.notice.content = f"_{escape_md(text)}_"
        self.notice.visible = True

    # -- events from the lab (any thread)

    def on_event(self, event: ChatEvent | MemberEvent) -> None:
        if isinstance(event, ChatEvent):
            self._lines.append(self._format(event.line))
        else:
            self.members = event.members
            who = escape_md(event.user)
            if event.status == "kicked":
                by = f" by {escape_md(event.by)}" if event.by else ""
                self._lines.append(f"_{who} was kicked{by}_")
                if event.user == self.connection.user:
                    self.client.add_notification(
                        title=f"Removed from {self.ctx}",
                        body=f"You were kicked{by}.",
                        color="red",
                    )
                    self.close(leave=False)
                    return
            else:
                self._lines.append(f"_{who} {event.status}_")
        self._render()

    # -- actions

    def submit(self) -> None:
        text = self.message.value
        problem = check_line(text)
        if problem:
            self.say_notice(problem)
            return
        try:
            self.connection.say(self.ctx, text)
        except LabError as exc:
            self.say_notice(f"Not sent: {exc}")
            return
        set_value(self.message, "")
        self.notice.visible = False

    def kick_selected(self) -> None:
        who = self.kick_who.value
        if who not in self._others():
            self.say_notice("Choose a member to kick.")
            return
        try:
            self.connection.kick(self.ctx, who)
        except LabError as exc:
            self.say_notice(f"Could not kick {who}: {exc}")

    def show_world(self) -> None:
        if self.world is None or self._on_watch is None:
            return
        try:
            feed = self.connection.world(self.world)
        except NotAnswering as exc:
            # Not up yet (an engine compiling on a busy machine's first start): said so,
            # and shown by itself once it answers, so the words never go stale.
            self.say_notice(f"Cannot show the arena yet: {exc}. It is shown once it answers.")
            self._retry_world()
            return
        except LabError as exc:
            self.say_notice(f"Cannot show the arena: {exc}")
            return
        self.notice.visible = False
        self._on_watch(feed, self)

    def _retry_world(self) -> None:
        with self._retry_lock:
            if self._retrying:
                return
            self._retrying = True

        def retry() -> None:
            try:
                while not self.closed:
                    time.sleep(WORLD_RETRY_S)
                    try:
                        feed = self.connection.world(self.world or "")
                    except NotAnswering:
                        continue
                    except LabError as exc:
                        self.say_notice(f"Cannot show the arena: {exc}")
                        return
                    if self.closed or self._on_watch is None:
                        return
                    self.notice.visible = False
                    if self.in_front:
                        self._on_watch(feed, self)
                    # Else shown when its tab comes to the front again (the client asks).
                    return
            finally:
                with self._retry_lock:
                    self._retrying = False

        threading.Thread(target=retry, name=f"world-{self.ctx}", daemon=True).start()

    def _show_replay(self, feed: ReplayFeed) -> None:
        """A recording of this arena in the view: the panels follow the replay's cursor."""
        if self._on_watch is not None:
            self._on_watch(feed, self)

    def close(self, *, leave: bool) -> None:
        self.closed = True
        self.release()
        if leave:
            try:
                self.connection.leave(self.ctx)
            except LabError as exc:
                log.info("leaving %s: %s", self.ctx, exc)
        self.tab.remove()
        self._on_close(self)

    def release(self) -> None:
        """Stop the parts that watch the lab for this page; the context stays joined."""
        self.closed = True
        for part in (self.recordings, self.course, self.klass):
            if part is not None:
                part.close()
        self.unbind()

    def memory(self) -> PanelMemory:
        """What a new page needs to draw this tab again as it was (see viewers/web/parking.py)."""
        return PanelMemory(
            joined=replace(self.joined, members=self.members),
            lines=tuple(self._lines),
            robots=self.robots.memory() if self.robots is not None else None,
            bench=self.workbench.memory() if self.workbench is not None else None,
        )

    def bind(self, view: WorldView, feed: WorldFeed) -> None:
        """This arena is now the one in the view: wire its robot panel and editor to it."""
        self.view = view
        if self.robots is not None:
            self.robots.bind(view, feed)
        if self.editor is not None:
            self.editor.bind(view, feed)
        if self.builder is not None:
            self.builder.bind(feed)

    def unbind(self) -> None:
        for part in (self.robots, self.editor, self.builder):
            if part is not None:
                part.unbind()
