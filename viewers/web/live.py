"""The viewer over the live lab (not the demo): the registry client and the world keys.

The viewer is a gateway. It holds one Zenoh session per lab router (its own
lab's, opened by ``wart viewer``, plus one per other lab a browser connects
to) and, per logged-in browser user, one :class:`~common.client.lab_client.LabClient` on
that session: every query, chat line, edit and admin request is sealed with
that person's session, so the services' ACL checks apply to the person.

The labs it knows and their router sessions are in lab_links.py, the worlds
it shows in live_world.py.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from common import keys, lab_errors
from common.ask import alive_keys
from common.client import host_client
from common.client import lab_client as lab
from common.client.lab_address import LabAddress
from common.client.survey import Survey, survey
from common.keys import AliveKind, is_ident
from common.messages import (
    AgentContextState,
    QueueStateRequest,
    RoomEvent,
)
from common.twin.twinfile import Twin, TwinFileError, parse_twin
from viewers.web.adapters import (
    AgentStatus,
    ArenaSettings,
    ChatEntry,
    ChatEvent,
    ContextSummary,
    Directory,
    DirectoryEvent,
    DisconnectedEvent,
    DryRunResult,
    JoinedContext,
    LabError,
    LabEvent,
    LoginUnavailable,
    MemberEvent,
    OutputSoFar,
    PrivateEvent,
    Queued,
    RecordingEntry,
    SavedFile,
    plain_error,
)
from viewers.web.lab_links import LabRouterLink
from viewers.web.live_admin import LiveAdmin
from viewers.web.live_agents import AgentContextLink
from viewers.web.live_courses import LiveCourses
from viewers.web.live_world import UserWorld

if TYPE_CHECKING:  # the connector makes connections; only its type is needed here
    from viewers.web.connector import LiveConnector

log = logging.getLogger("wart.viewer.live")

DIRECTORY_POLL_S = 3.0  # the registry has no directory events: poll, emit on change
HISTORY = 50  # chat lines a join asks for
NOT_AN_ARENA = (
    "this is a world without an agent context: robots are queued and driven through an "
    "agent context (join one from the lobby)"
)


# --- one user's connection ----------------------------------------------------------------


@dataclass
class _Worldish:
    """A directory entry for a running world that no agent context announces (yet)."""

    world: str


@dataclass
class _Events:
    subscribers: dict[int, Callable[[LabEvent], None]] = field(default_factory=dict)
    next_id: int = 1


class LiveConnection:
    """One browser user's session with one lab, over a :class:`LabClient`."""

    def __init__(
        self,
        connector: LiveConnector,
        link: LabRouterLink,
        client: lab.LabClient,
        address: LabAddress,
    ) -> None:
        self.connector = connector
        self.link = link
        self.client = client
        self._address = address
        self._admin = LiveAdmin(client, self._call)
        session = client.session
        assert session is not None
        self._perms = frozenset(session.token.permissions)
        self._grants = {scope: frozenset(g) for scope, g in session.token.grants.items()}
        self._events = _Events()
        self._lock = threading.Lock()
        self._queue: queue.SimpleQueue[LabEvent | None] = queue.SimpleQueue()
        self._closed = threading.Event()
        self._directory: Directory | None = None
        self._kinds: dict[str, ContextSummary] = {}
        self._worlds: dict[str, UserWorld] = {}
        self._world_only: set[str] = set()
        self._arenas: dict[str, AgentContextLink] = {}  # joined agent contexts
        self._real_worlds: dict[str, bool] = {}  # world -> a Khepera bridge (asked once)
        self._ctx_worlds: dict[str, str] = {}  # agent context -> its world (never changes)
        self._courses = LiveCourses(client, self._call)
        client.on_private = lambda m: self._queue.put(PrivateEvent(m.sender, m.text, m.sent_at))
        client.on_kicked = lambda k: self._queue.put(
            DisconnectedEvent(
                f"kicked from the server by {k.by}" + (f": {k.reason}" if k.reason else "")
            )
        )
        for kept in client.pending:
            self._queue.put(PrivateEvent(kept.sender, kept.text, kept.sent_at))
        # Events are delivered on this thread, never on Zenoh's: a subscriber may query.
        self._thread = threading.Thread(target=self._run, name=f"lab-{address.user}", daemon=True)
        self._thread.start()

    # -- identity

    @property
    def address(self) -> LabAddress:
        return self._address

    @property
    def user(self) -> str:
        return self._address.user or ""

    @property
    def permissions(self) -> frozenset[str]:
        return self._perms

    def _may(self, permission: str, ctx: str) -> bool:
        return permission in self._perms or permission in self._grants.get(f"ctx/{ctx}", ())

    @property
    def admin(self) -> LiveAdmin:
        return self._admin

    @property
    def courses(self) -> LiveCourses:
        return self._courses

    def _call(self, fn: Callable[[], Any]) -> Any:
        if self._closed.is_set():
            raise LabError("you are logged out of this lab")
        try:
            return fn()
        except lab_errors.LabError as exc:
            raise plain_error(exc, self._address) from None

    # -- events

    def subscribe(self, callback: Callable[[LabEvent], None]) -> Callable[[], None]:
        with self._lock:
            sub = self._events.next_id
            self._events.next_id += 1
            self._events.subscribers[sub] = callback

        def unsubscribe() -> None:
            with self._lock:
                self._events.subscribers.pop(sub, None)

        return unsubscribe

    def _run(self) -> None:
        while not self._closed.is_set():
            try:
                event = self._queue.get(timeout=DIRECTORY_POLL_S)
            except queue.Empty:
                event = self._poll_directory()
            if event is None:
                continue
            with self._lock:
                targets = list(self._events.subscribers.values())
            for callback in targets:
                try:
                    callback(event)
                except Exception:
                    log.exception(
                        "a subscriber of %s failed on %s", self.user, type(event).__name__
                    )

    def _poll_directory(self) -> LabEvent | None:
        if not self._events.subscribers:
            return None
        before = self._directory
        try:
            after = self.directory()
        except LabError as exc:
            log.debug("directory poll for %s: %s", self.user, exc)
            return None
        return DirectoryEvent() if after != before else None

    def _room_event(self, ctx: str, event: RoomEvent) -> None:
        """A LabClient callback (Zenoh thread): translate and queue, nothing more."""
        members = tuple(event.members)
        if event.line is not None:
            line = event.line
            self._queue.put(ChatEvent(ctx, ChatEntry(line.seq, line.sender, line.text, line.at)))
        if event.status is not None:
            status = event.status
            kind: Literal["joined", "left", "kicked"] = (
                status.status if status.status in ("joined", "kicked") else "left"
            )
            self._queue.put(MemberEvent(ctx, status.user, kind, members, status.by, status.reason))
            self._queue.put(DirectoryEvent())

    # -- directory, contexts, chat

    def check_resume(self) -> None:
        if self._closed.is_set():
            raise LabError("you are logged out of this lab")
        try:
            self.client.check_resume()
        except (lab_errors.RegistryUnreachable, lab_errors.RateLimited) as exc:
            # Not asked is not refused: the parked session must not end for it.
            raise LoginUnavailable(str(plain_error(exc, self._address))) from None
        except lab_errors.LabError as exc:
            raise plain_error(exc, self._address) from None

    def directory(self) -> Directory:
        reply = self._call(self.client.directory)
        contexts = [
            ContextSummary(
                c.ctx, c.kind, c.owner, c.title, len(c.members), self._world_of(c.ctx, c.kind)
            )
            for c in reply.contexts
        ]
        named = {c.ctx for c in contexts} | {c.world for c in contexts if c.world}
        # Running engines (and bridges) no agent context announces appear too, so their
        # arenas can be watched (and edited) before a context queues their robots.
        for world in sorted(self._live_worlds()):
            if world not in named:
                contexts.append(
                    ContextSummary(world, "world", "engine", f"world {world}", 0, world)
                )
        directory = Directory(reply.server_name, tuple(reply.users), tuple(contexts))
        with self._lock:
            self._directory = directory
            self._kinds = {c.ctx: c for c in contexts}
        return directory

    def _world_of(self, ctx: str, kind: str) -> str | None:
        """An agent context's world, from its queue state (asked once per context)."""
        if kind != "agent":
            return None
        world = self._ctx_worlds.get(ctx)
        if world is None:
            try:
                state = self.client.request(
                    ctx, QueueStateRequest(), AgentContextState, f"queues of {ctx}"
                )
            except lab_errors.LabError as exc:  # not answering yet: the next poll asks again
                log.debug("world of %s: %s", ctx, exc)
                return None
            world = self._ctx_worlds[ctx] = state.world
        return world

    def _live_worlds(self) -> set[str]:
        worlds: set[str] = set()
        realm = self._address.realm
        try:
            found = alive_keys(
                self.link.session,
                keys.alive_of_kind(realm, AliveKind.WORLD),
                what="worlds",
                timeout=2.0,
            )
        except LabError as exc:
            log.debug("listing worlds: %s", exc)
            return worlds
        for key in found:
            parsed = keys.parse_alive(realm, key)
            if parsed is not None:
                worlds.add(parsed[1])
        return worlds

    def join(self, ctx: str) -> JoinedContext:
        if not is_ident(ctx):
            raise LabError(f"{ctx!r} is not a context name")
        summary = self._kinds.get(ctx)
        if summary is None:
            self.directory()
            summary = self._kinds.get(ctx)
        if summary is not None and summary.kind == "world":
            self._world_only.add(ctx)
            return JoinedContext(
                ctx=ctx,
                kind="world",
                title=summary.title,
                owner=summary.owner,
                members=(self.user,),
                history=(),
                world=summary.world,
            )
        if summary is not None and summary.kind != "unknown":
            kind, world = summary.kind, summary.world
        else:
            # Not listed yet, or listed as "unknown" (on a busy machine the registry may
            # not have seen it come up, or it did not answer the registry within 1 s):
            # an agent context answers for its queues, a chat room does not. Taken for
            # a chat room, an arena showed its chat and nothing else.
            world = self._world_of(ctx, "agent")
            kind = "agent" if world is not None else "chat"
        if kind == "agent":
            # An agent context: chat and AgentEvents (queues, output) over one join.

            def on_room(event: RoomEvent) -> None:
                self._room_event(ctx, event)

            arena = self._call(lambda: AgentContextLink(self.client, ctx, self._queue.put, on_room))
            room = arena.join(HISTORY)
            world = arena.world or world
            if world is not None:
                self._ctx_worlds[ctx] = world
            with self._lock:
                self._arenas[ctx] = arena
        else:
            room = self._call(
                lambda: self.client.join(ctx, lambda e: self._room_event(ctx, e), HISTORY)
            )
        history = tuple(ChatEntry(h.seq, h.sender, h.text, h.at) for h in room.history)
        return JoinedContext(
            ctx=ctx,
            kind=kind,
            title=room.title,
            owner=room.owner,
            members=tuple(room.members),
            history=history,
            world=world,
            can_kick=self._may("kick", ctx) or room.owner == self.user,
        )

    def leave(self, ctx: str) -> None:
        if ctx in self._world_only:
            self._world_only.discard(ctx)
            return
        with self._lock:
            self._arenas.pop(ctx, None)
        self._call(lambda: self.client.leave(ctx))

    def say(self, ctx: str, text: str) -> None:
        if ctx in self._world_only:
            raise LabError(f"{ctx} has no chat room: {NOT_AN_ARENA}")
        self._call(lambda: self.client.say(ctx, text))

    def kick(self, ctx: str, user: str, reason: str = "") -> None:
        self._call(lambda: self.client.kick(ctx, user, reason))

    def host(self, kind: Literal["chat", "agent"], name: str, map_name: str = "") -> str:
        """Start a new context on one of the lab's hosts (``host`` permission), as this user.

        Blocks until its processes serve (seconds); the lobby calls it off the
        page's thread. An arena's agent context is named after its world.
        """
        if kind == "chat":
            room = self._call(lambda: host_client.host_room(self.client, name, name))
            return room.name
        if not map_name:
            raise LabError("choose a map for the new arena")
        arena = self._call(lambda: host_client.host_arena(self.client, name, map_name))
        return arena.world

    def survey(self) -> Survey:
        """What the lab looks like from the viewer (admins' network page)."""
        if "admin" not in self._perms:
            raise LabError("only admins can survey the lab's network")
        return survey(self.client.z, self._address.realm)

    def send_private(self, to: str, text: str) -> None:
        self._call(lambda: self.client.send_private(to, text))

    # -- worlds

    def world(self, world: str) -> UserWorld:
        if self._closed.is_set():
            raise LabError("you are logged out of this lab")
        existing = self._worlds.get(world)
        if existing is not None:
            return existing
        feed = UserWorld(self.link.watch(world), self)
        self._worlds[world] = feed
        return feed

    # -- agents: the joined agent contexts' queues, uploads and settings

    def _arena(self, ctx: str) -> AgentContextLink:
        if self._closed.is_set():
            raise LabError("you are logged out of this lab")
        arena = self._arenas.get(ctx)
        if arena is None:
            if ctx in self._world_only:
                raise LabError(f"{ctx}: {NOT_AN_ARENA}")
            raise LabError(f"join {ctx} first")
        return arena

    def _offline(self, world: str | None) -> frozenset[str]:
        feed = self._worlds.get(world or "")
        if feed is None:
            return frozenset()
        try:
            return feed.snapshot().offline
        except LabError:
            return frozenset()

    def agents(self, ctx: str) -> list[AgentStatus]:
        """The robots and their queues; a world without context lists its robots only."""
        arena = self._arenas.get(ctx)
        if arena is not None:
            return arena.rows(self._offline(arena.world))
        summary = self._kinds.get(ctx)
        world = self._worlds.get(summary.world or "") if summary is not None else None
        if world is None:
            return []  # the world is not shown yet; RobotPanel.bind asks again
        snap = world.snapshot()
        return [
            AgentStatus(name, None, 0, enabled=False, online=name not in snap.offline)
            for name in snap.robots
        ]

    def request_control(self, ctx: str, agent: str, filename: str, source: bytes) -> Queued:
        return self._arena(ctx).request(agent, filename, source)

    def cancel_control(self, ctx: str, agent: str) -> str:
        return self._arena(ctx).cancel(agent)

    def arena_settings(self, ctx: str) -> ArenaSettings:
        arena = self._arenas.get(ctx)
        if arena is None:
            return ArenaSettings(slot_seconds=0.0, enabled=False, can_manage=False)
        return arena.settings(self._may("kick", ctx))

    def set_slot(self, ctx: str, seconds: float) -> str:
        return self._arena(ctx).set_slot(seconds)

    def stop_agent(self, ctx: str, agent: str) -> str:
        return self._arena(ctx).stop(agent)

    def take_over(self, ctx: str, agent: str, take: bool) -> str:
        return self._arena(ctx).take_over(agent, take)

    def drive(self, ctx: str, agent: str, left: int, right: int) -> None:
        self._arena(ctx).drive(agent, left, right)

    def set_enabled(self, ctx: str, enabled: bool, agent: str | None = None) -> str:
        return self._arena(ctx).set_enabled(enabled, agent)

    # -- the editor

    def list_files(self, ctx: str) -> list[SavedFile]:
        return self._arena(ctx).list_files()

    def read_file(self, ctx: str, name: str) -> bytes:
        return self._arena(ctx).read_file(name)

    def save_file(self, ctx: str, name: str, source: bytes) -> str:
        return self._arena(ctx).save_file(name, source)

    def reset_robot(self, ctx: str, agent: str) -> str:
        world = self._arena(ctx).world
        if world is None:
            raise LabError(f"{ctx} has not said which world it drives yet: try again")
        return self.world(world).reset(agent)

    def output_so_far(self, ctx: str, request_id: str) -> OutputSoFar:
        return self._arena(ctx).output_so_far(request_id)

    def recordings(self, ctx: str) -> list[RecordingEntry]:
        return self._arena(ctx).recordings()

    def fetch_recording(self, ctx: str, name: str, dest: Path) -> Path:
        return self._arena(ctx).fetch_recording(name, dest)

    def promote(self, ctx: str, agent: str, recording: Path) -> Queued:
        return self._arena(ctx).promote(agent, recording)

    def save_twin(self, ctx: str, robot: str, document: str) -> str:
        saved = self._call(lambda: self.client.twins.save(document, robot, ctx))
        where = f" in {saved.arena}" if saved.arena else ""
        return f"Kept {saved.model} as {saved.robot}'s twin{where} v{saved.version} (in force)."

    def twin(self, ctx: str, robot: str) -> Twin | None:
        reply = self._call(lambda: self.client.twins.of(robot, ctx))
        if reply.current is None:
            return None
        try:  # checked again by whoever reads it: the registry's row is outside input
            return parse_twin(reply.current.document, f"{robot}'s twin")
        except TwinFileError as exc:
            raise LabError(str(exc)) from None

    def _is_real(self, world: str) -> bool:
        """Whether ``world`` is a Khepera bridge (asked once: a world does not change kind)."""
        known = self._real_worlds.get(world)
        if known is None:
            feed = self.world(world)
            feed.source.ready()
            known = self._real_worlds[world] = feed.snapshot().real
        return known

    def real_robots(self) -> list[tuple[str, str]]:
        found = []
        for ctx, arena in list(self._arenas.items()):
            world = arena.world
            try:
                if world is None or not self._is_real(world):
                    continue
                found += [(ctx, row.agent) for row in arena.rows(self._offline(world))]
            except LabError as exc:
                log.info("is %s real? %s", ctx, exc)
        return found

    def emergency_stop(self, ctx: str, engaged: bool, reason: str = "") -> str:
        return self._arena(ctx).emergency_stop(engaged, reason)

    def dry_run(self, ctx: str, agent: str, filename: str, source: bytes) -> DryRunResult:
        return self._arena(ctx).dry_run(agent, filename, source)

    # -- the end

    @property
    def resume_token(self) -> bytes | None:
        return self.client.resume_token

    def logout(self, keep_resume: bool = False, reason: str = "") -> None:
        """Leave every room, log out (presence goes), release worlds; safe to call twice."""
        self._end(logout=True, keep_resume=keep_resume, reason=reason)

    def hand_over(self) -> None:
        self._end(logout=False, keep_resume=True, reason="")

    def _end(self, *, logout: bool, keep_resume: bool, reason: str) -> None:
        if self._closed.is_set():
            return
        self._closed.set()
        self.client.keep_resume = keep_resume
        with self._lock:
            self._events.subscribers.clear()
        self._queue.put(None)
        for feed in list(self._worlds.values()):
            self.link.release(feed.source)
        self._worlds.clear()
        if not logout:  # a logout hands them back in the context itself (revocation)
            for arena in list(self._arenas.values()):
                arena.hand_back_all("the web viewer stopped")
        self._arenas.clear()
        self._courses.close()
        try:
            # leaves rooms, logs out (unless handed over), undeclares the presence token
            self.client.close(reason, logout=logout)
        except Exception:
            log.exception("logging %s out of %s", self.user, self._address.label)
        self.connector._closed(self)
