"""One lab's lobby tab (thesis 7.3.3): server name, who is online, contexts, host, messages.

A :class:`LabTab` owns the user's connection to that lab, dispatches the
lab's events to the lobby and to the context tabs it opened, and logs out.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Callable

import viser

from common.acl import account_in_words
from common.keys import is_ident
from viewers.web.adapters import (
    AgentsEvent,
    ChatEvent,
    Directory,
    DirectoryEvent,
    DisconnectedEvent,
    JoinedContext,
    LabConnection,
    LabError,
    LabEvent,
    MemberEvent,
    OutputEvent,
    PrivateEvent,
    RequestEvent,
)
from viewers.web.admin_panel import AdminPanel
from viewers.web.chat_panel import ChatPanel, PanelMemory
from viewers.web.inputs import on_click, set_value
from viewers.web.login import MAX_PASSWORD
from viewers.web.masked import add_masked_text
from viewers.web.network_panel import NetworkPanel
from viewers.web.parking import EventKeeper, LabMemory, ParkedLab
from viewers.web.tabs import tab_label
from viewers.web.text import check_line, clock, escape_md
from viewers.web.workbench import BenchMemory, Workbench
from viewers.web.world_feed import WorldFeed

log = logging.getLogger("wart.viewer.lobby")

KIND_NAMES = {"chat": "chat room", "agent": "arena", "world": "world (watch; edit if simulated)"}


class LabTab:
    def __init__(
        self,
        client: viser.ClientHandle,
        tabs: viser.GuiTabGroupHandle,
        connection: LabConnection,
        *,
        on_logout: Callable[[LabTab], None],
        on_watch: Callable[[WorldFeed, ChatPanel], None],
        on_context: Callable[[ChatPanel], None] | None = None,
        on_context_closed: Callable[[ChatPanel], None] | None = None,
        kept: ParkedLab | None = None,
    ) -> None:
        """``kept``: a session parked by a page that went away, drawn again as it was."""
        self.client = client
        self.tabs = tabs
        self.connection = connection
        self.panels: dict[str, ChatPanel] = {}
        self._joining: set[str] = set()  # contexts whose join is under way
        self._on_logout = on_logout
        self._on_watch = on_watch
        self._on_context = on_context
        self._on_context_closed = on_context_closed
        self._lock = threading.RLock()
        self._directory: Directory | None = None
        # Each context's row in the directory: its line and its Join button.
        self._rows: dict[str, tuple[viser.GuiMarkdownHandle, viser.GuiButtonHandle]] = {}
        self._private: list[str] = []
        self.closed = False
        gui = client.gui
        # Short enough to read in a tab; the full address is its hover title (tabs.py).
        self.tab_name = tab_label(connection.address)
        # Held back until its handlers are registered, as the chat panels are (chat_panel.py).
        with client.atomic():
            self.tab = tabs.add_tab(self.tab_name, icon=viser.Icon.HOME)
            with self.tab:
                self.header = gui.add_markdown("")
                self.online = gui.add_markdown("")
                self.contexts = gui.add_folder("Contexts")
                can_host = "host" in connection.permissions
                with gui.add_folder(
                    "Host a new context", visible=can_host, expand_by_default=False
                ):
                    self.host_name = gui.add_text("Name", "")
                    # A map of the lab (STATE_DIR/maps, then the shipped ones): empty, maze,
                    # foraging, phototaxis, swarm.
                    self.host_map = gui.add_text("Map (arena)", "foraging")
                    self.host_chat = gui.add_button("Host chat room")
                    self.host_arena = gui.add_button("Host arena")
                with gui.add_folder("Private messages", expand_by_default=False):
                    self.pm_log = gui.add_markdown("_None yet._")
                    self.pm_to = gui.add_text("To", "")
                    self.pm_text = gui.add_text("Private message", "")
                    self.pm_send = gui.add_button("Send privately")
                with gui.add_folder("My account", expand_by_default=False):
                    # A class's first passwords come on paper (wart users import): each
                    # student sets their own here.
                    # The current one too, unless this page just logged in with it: a saved
                    # login (a cookie) alone never sets the password.
                    self.my_current = add_masked_text(gui, "My current password")
                    self.my_password = add_masked_text(
                        gui, "My new password", submit="Set my password"
                    )
                    self.my_password_button = gui.add_button("Set my password")
                    self.my_password_said = gui.add_markdown("")
                is_admin = "admin" in connection.permissions
                self.admin = AdminPanel(client, connection) if is_admin else None
                self.network = NetworkPanel(client, connection) if is_admin else None
                self.notice = gui.add_markdown("", visible=False)
                self.logout_button = gui.add_button("Log out", color="gray")
            self.my_password_button.on_click(lambda _: self.set_my_password())
            self.host_chat.on_click(lambda _: self.host("chat"))
            self.host_arena.on_click(lambda _: self.host("agent"))
            self.pm_send.on_click(lambda _: self.send_private())
            self.logout_button.on_click(lambda _: self.logout())
        if kept is None:
            self._unsubscribe = connection.subscribe(self.on_event)
        else:
            for memory in kept.memory.panels:
                self._add_panel(memory.joined, memory)
            self._private = list(kept.memory.private)
            if self._private:
                self.pm_log.content = "  \n".join(self._private)
            # The events of the time away, then the live ones: in order, none twice.
            self._unsubscribe = kept.events.hand_to(self.on_event)
        self.refresh()

    @property
    def label(self) -> str:
        return self.connection.address.label

    def set_my_password(self) -> None:
        password, current = self.my_password.value, self.my_current.value
        set_value(self.my_password, "")  # never left on screen
        set_value(self.my_current, "")
        if not password or len(password) > MAX_PASSWORD:  # the registry says the minimum
            self.my_password_said.content = "_Type your new password first._"
            return
        try:
            admin = self.connection.admin
            admin.set_password(self.connection.user, password, current[:MAX_PASSWORD] or None)
        except LabError as exc:
            self.my_password_said.content = f"_Refused: {escape_md(str(exc))}_"
            return
        self.my_password_said.content = "**Your password is changed**: use it at your next login."

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    # -- directory

    def refresh(self) -> None:
        try:
            directory = self.connection.directory()
        except LabError as exc:
            self.say_notice(f"Could not read the directory: {exc}")
            return
        with self._lock:
            if directory == self._directory:
                return
            self._directory = directory
            self.header.content = (
                f"### {escape_md(directory.server_name)}\n"
                f"Logged in as **{escape_md(self.connection.user)}**"
            )
            self.online.content = "Online: " + (
                ", ".join(escape_md(account_in_words(u)) for u in directory.users) or "nobody"
            )
            # Rows are updated in place, added and removed one by one: rebuilding them all
            # made the page log "Tried to update non-existent component" for the clicked
            # Join button's own updates, sent after it had been removed.
            shown = {c.ctx for c in directory.contexts}
            for ctx in [ctx for ctx in self._rows if ctx not in shown]:
                for handle in self._rows.pop(ctx):
                    handle.remove()
            gui = self.client.gui
            with self.contexts:
                for c in directory.contexts:
                    kind = KIND_NAMES.get(c.kind, c.kind)
                    text = (
                        f"**{escape_md(c.ctx)}** · {kind} · owner {escape_md(c.owner)} · "
                        f"{c.members} member{'s' if c.members != 1 else ''}"
                    )
                    joined = c.ctx in self.panels
                    row = self._rows.get(c.ctx)
                    if row is None:
                        line = gui.add_markdown(text)
                        button = gui.add_button(f"Join {c.ctx}", disabled=joined, color="blue")
                        on_click(button, functools.partial(self.join, c.ctx))
                        self._rows[c.ctx] = (line, button)
                        continue
                    markdown, button = row
                    if markdown.content != text:
                        markdown.content = text
                    if button.disabled != joined:
                        button.disabled = joined

    # -- actions

    def join(self, ctx: str, editor: BenchMemory | None = None) -> ChatPanel | None:
        """Join ``ctx`` and open its tab; ``editor``: its editor's text, put back."""
        who = f"{self.connection.user} on {self.label}"
        with self._lock:
            if ctx in self.panels:
                return self.panels[ctx]
            if ctx in self._joining:
                # Clicked again while the first join waits on a busy lab: one join, one tab
                # (two made two subscriptions to the room and two chat panels for it).
                log.info("%s: already joining %s", who, ctx)
                return None
            self._joining.add(ctx)
        try:
            return self._join(ctx, who, editor)
        finally:
            with self._lock:
                self._joining.discard(ctx)

    def _join(self, ctx: str, who: str, editor: BenchMemory | None) -> ChatPanel | None:
        # Logged both ways, as hosting is: a page whose joined context never showed its
        # tab (a busy run) left no trace of whether the join was asked, answered or failed.
        log.info("%s: joining %s", who, ctx)
        started = time.monotonic()
        try:
            joined = self.connection.join(ctx)
        except LabError as exc:
            log.warning("%s: could not join %s: %s", who, ctx, exc)
            self.say_notice(f"Could not join {ctx}: {exc}")
            return None
        log.info("%s: joined %s in %.1f s", who, ctx, time.monotonic() - started)
        panel = self._add_panel(joined, editor=editor)
        self._directory = None  # the Join button's state changed
        self.refresh()
        for bench in self._workbenches():  # a real arena joined: its robots join the lists
            if bench is not panel.workbench:
                bench.refresh_targets()
        if self._on_context is not None:
            self._on_context(panel)
        return panel

    def _add_panel(
        self,
        joined: JoinedContext,
        kept: PanelMemory | None = None,
        editor: BenchMemory | None = None,
    ) -> ChatPanel:
        panel = ChatPanel(
            self.client,
            self.tabs,
            self.connection,
            joined,
            on_close=self._panel_closed,
            on_watch=self._on_watch,
            kept=kept,
            editor=editor,
        )
        with self._lock:
            self.panels[joined.ctx] = panel
        return panel

    def _workbenches(self) -> list[Workbench]:
        with self._lock:
            panels = list(self.panels.values())
        return [p.workbench for p in panels if p.workbench is not None]

    def _panel_closed(self, panel: ChatPanel) -> None:
        with self._lock:
            self.panels.pop(panel.ctx, None)
        for bench in self._workbenches():  # a real arena left: its robots leave the lists
            bench.refresh_targets()
        if self._on_context_closed is not None:
            self._on_context_closed(panel)
        self._directory = None
        self.refresh()

    def host(self, kind: str) -> None:
        name = self.host_name.value.strip()
        if not is_ident(name):
            self.say_notice("Give the new context a name: letters, digits, '_', '-' or '.'.")
            return
        map_name = self.host_map.value.strip() if kind == "agent" else ""
        self.say_notice(f"Starting {name}: this takes a few seconds...")
        # Logged both ways: a page whose new context never showed left no trace before.
        who = f"{self.connection.user} on {self.label}"
        log.info("%s: hosting %s %s", who, kind, name)
        started = time.monotonic()
        try:
            ctx = self.connection.host("agent" if kind == "agent" else "chat", name, map_name)
        except LabError as exc:
            took = time.monotonic() - started
            log.info("%s: hosting %s ended after %.1f s: %s", who, name, took, exc)
            self.say_notice(f"Could not host {name}: {exc}")
            return
        log.info("%s: %s is up after %.1f s; joining it", who, ctx, time.monotonic() - started)
        set_value(self.host_name, "")
        self.join(ctx)

    def send_private(self) -> None:
        to = self.pm_to.value.strip()
        text = self.pm_text.value
        if not is_ident(to):
            self.say_notice("Write the user name of who the message is for.")
            return
        problem = check_line(text)
        if problem:
            self.say_notice(problem)
            return
        try:
            self.connection.send_private(to, text)
        except LabError as exc:
            self.say_notice(f"Not sent: {exc}")
            return
        set_value(self.pm_text, "")
        self._add_private(f"to **{escape_md(to)}**: {escape_md(text)}")

    def _add_private(self, line: str) -> None:
        self._private = [*self._private[-19:], line]
        self.pm_log.content = "  \n".join(self._private)

    def park(self, watching: str | None) -> tuple[LabMemory, EventKeeper]:
        """The browser went away: keep the lab session, its tabs' state and its events.

        ``watching``: the context whose world the page showed. The keeper listens
        before this tab stops, so no event falls between them.
        """
        events = EventKeeper(self.connection)
        self.closed = True
        self._unsubscribe()
        with self._lock:
            panels = list(self.panels.values())
        memory = LabMemory(
            panels=tuple(panel.memory() for panel in panels),
            private=tuple(self._private),
            watching=watching,
        )
        for panel in panels:
            panel.release()
        return memory, events

    def shutdown(self) -> None:
        """The browser went away: end the lab session without touching its (closed) page."""
        self.closed = True
        self._unsubscribe()
        try:
            # leaves rooms; the user's presence goes; a reload may resume (saved_login.py)
            self.connection.logout(keep_resume=True)
        except LabError as exc:
            log.info("logout from %s: %s", self.label, exc)

    def hand_over(self) -> None:
        """The viewer stops: the lab session goes on without it (see LabConnection)."""
        self.closed = True
        self._unsubscribe()
        self.connection.hand_over()

    def logout(self) -> None:
        self.closed = True
        self._unsubscribe()
        for panel in list(self.panels.values()):
            panel.close(leave=True)
        try:
            self.connection.logout()
        except LabError as exc:
            log.info("logout from %s: %s", self.label, exc)
        self.tab.remove()
        self._on_logout(self)

    # -- events (the connection's threads)

    def on_event(self, event: LabEvent) -> None:
        if self.closed:
            return  # a late event for a page that is gone or a lab logged out of
        try:
            self._dispatch(event)
        except Exception:
            # A GUI update for a browser that just went away must not break the lab's thread.
            log.exception("could not show an event from %s", self.label)

    def _dispatch(self, event: LabEvent) -> None:
        if isinstance(event, ChatEvent | MemberEvent):
            panel = self.panels.get(event.ctx)
            if panel is not None:
                panel.on_event(event)
        elif isinstance(event, DirectoryEvent):
            self.refresh()
        elif isinstance(event, PrivateEvent):
            self._add_private(
                f"`{clock(event.at)}` from **{escape_md(event.sender)}**: {escape_md(event.text)}"
            )
            set_value(self.pm_to, event.sender)  # answering is one click on Send
            self.client.add_notification(
                title=f"Message from {event.sender} ({self.label})",
                body=event.text[:200],
                auto_close_seconds=10.0,
            )
        elif isinstance(event, AgentsEvent | RequestEvent | OutputEvent):
            panel = self.panels.get(event.ctx)
            if isinstance(event, AgentsEvent):
                for bench in self._workbenches():  # their lists hold the real arenas' robots
                    if bench.ctx != event.ctx:
                        bench.refresh_targets()
            robots = panel.robots if panel is not None else None
            if robots is None:
                return
            if isinstance(event, AgentsEvent):
                robots.refresh_agents()
            elif isinstance(event, RequestEvent):
                robots.on_request(event)
                for bench in self._workbenches():  # a real run may come from another arena's
                    bench.on_request(event)
            else:
                robots.on_output(event)
                for bench in self._workbenches():
                    bench.on_output(event)
        elif isinstance(event, DisconnectedEvent):
            self.client.add_notification(
                title=f"Disconnected from {self.label}", body=event.reason, color="red"
            )
            self.logout()
