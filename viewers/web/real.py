"""The viewer's Protocols over the real lab: the registry client and the engine's world keys.

The viewer is a gateway. It holds one Zenoh session per lab router (its own
lab's, opened by ``wart viewer``, plus one per other lab a browser connects
to) and, per logged-in browser user, one :class:`~common.client.LabClient` on
that session: every query, chat line, edit and admin request is sealed with
that person's session, so the services' ACL checks apply to the person.

Worlds are watched once per lab and world (:class:`WorldWatch`), shared by
every browser: a short subscriber callback keeps only the newest frame's
bytes; the pump's ``latest()`` decodes it at most once per new frame; a frame
whose layout differs from the snapshot's wakes a thread that refetches the
snapshot (Zenoh queries never run inside Zenoh callbacks). Edits go through a
per-user :class:`UserWorld` that seals them with that user's session.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import zenoh

from common import client as lab
from common import host_client, keys
from common.auth import parse_public_key
from common.keys import AliveKind, is_ident
from common.messages import (
    AddItem,
    AgentContextState,
    EditResult,
    ErrorReply,
    MapRequest,
    Message,
    MessageError,
    MoveItem,
    QueueStateRequest,
    RemoveItem,
    ResizeArena,
    RoomEvent,
    SensorSample,
    WorldEdit,
    WorldFrame,
    WorldSnapshot,
    decode,
)
from common.service import close_session, open_session
from common.survey import Survey, survey
from common.zconfig import NetworkOptions
from viewers.web.adapters import (
    Account,
    AgentStatus,
    ArenaSettings,
    Ball,
    ChatEntry,
    ChatEvent,
    ContextSummary,
    Directory,
    DirectoryEvent,
    DisconnectedEvent,
    JoinedContext,
    LabError,
    LabEvent,
    Light,
    LoginError,
    MapEdit,
    MemberEvent,
    Obstacle,
    PrivateEvent,
    Queued,
    RobotReadings,
    SceneFrame,
    SceneLayout,
)
from viewers.web.address import AddressError, LabAddress, parse_address
from viewers.web.real_agents import ArenaLink
from viewers.web.world_view import OFFLINE

log = logging.getLogger("wart.viewer.real")

QUERY_TIMEOUT = 5.0
DIRECTORY_POLL_S = 3.0  # the registry has no directory events: poll, emit on change
SENSOR_IDLE_S = 5.0  # a robot's sensor subscription ends when nobody asked for it this long
HISTORY = 50  # chat lines a join asks for
NOT_AN_ARENA = (
    "this is a world without an agent context: robots are queued and driven through an "
    "agent context (join one from the lobby)"
)
LABS_FILE = "labs.json"


def _plain(exc: lab.LabError, address: LabAddress) -> LabError:
    """The registry client's errors, in the words the page shows."""
    if isinstance(exc, lab.RegistryUnreachable):
        return LabError(f"the lab at {address.label} does not answer (is its registry running?)")
    if isinstance(exc, lab.NotAllowed):
        return LabError(f"not allowed: {exc}")
    if isinstance(exc, lab.NotLoggedIn):
        return LabError("your session with this lab has ended: log in again")
    if isinstance(exc, lab.RateLimited):
        return LabError(f"too many requests: try again in {exc.retry_after:.0f} s")
    return LabError(str(exc))


# --- the labs this viewer knows --------------------------------------------------------


@dataclass(frozen=True)
class KnownLab:
    address: LabAddress
    registry_key: bytes
    name: str = ""


def load_labs(path: Path | None, default_realm: str) -> dict[tuple[str, int, str], KnownLab]:
    """Read the admin-kept lab list (``DATA_DIR/labs.json``); bad entries are logged and skipped.

    Format: ``{"labs": [{"address": "wart://host:7447/realm", "registry_key": "HEX",
    "name": "..."}]}``. Only labs listed here (and the viewer's own) can be
    logged in to: a registry key is never learnt from whoever answers.
    """
    if path is None or not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        log.warning("%s is unreadable, no other labs are known: %s", path, exc)
        return {}
    out: dict[tuple[str, int, str], KnownLab] = {}
    entries = data.get("labs", []) if isinstance(data, dict) else []
    for i, entry in enumerate(entries if isinstance(entries, list) else []):
        try:
            if not isinstance(entry, dict):
                raise ValueError("not an object")
            address = parse_address(str(entry["address"]), default_realm=default_realm)
            key = parse_public_key(str(entry["registry_key"]))
            known = KnownLab(address.with_user(None), key, str(entry.get("name", "")))
        except (KeyError, ValueError, AddressError) as exc:
            log.warning("%s: labs[%d] skipped: %s", path, i, exc)
            continue
        out[address.lab_key] = known
    return out


# --- one router's session, shared by everyone logged in through it -----------------------


class LabLink:
    """A Zenoh session to one lab's router, its pinned registry key, and its world watches."""

    def __init__(
        self, address: LabAddress, session: zenoh.Session, registry_key: bytes, *, own: bool
    ) -> None:
        self.address = address
        self.session = session
        self.registry_key = registry_key
        self.own = own  # the viewer's own session: never closed here
        self.users = 0
        self._watches: dict[str, WorldWatch] = {}
        self._lock = threading.Lock()

    def watch(self, world: str) -> WorldWatch:
        with self._lock:
            watch = self._watches.get(world)
            if watch is None or watch.closed:
                watch = WorldWatch(self.session, self.address.realm, world)
                self._watches[world] = watch
            watch.users += 1
        try:
            watch.ready()
        except LabError:
            self.release(watch)
            raise
        return watch

    def release(self, watch: WorldWatch) -> None:
        with self._lock:
            watch.users -= 1
            if watch.users > 0:
                return
            if self._watches.get(watch.world) is watch:
                del self._watches[watch.world]
        watch.close()

    def close(self) -> None:
        with self._lock:
            watches = list(self._watches.values())
            self._watches.clear()
        for watch in watches:
            watch.close()
        if not self.own:
            close_session(self.session)


class RealConnector:
    """Logs browsers in to labs: the viewer's own, or one listed in the admin's labs file."""

    def __init__(
        self,
        own_session: zenoh.Session,
        own_address: LabAddress,
        own_registry_key: bytes | str | None,
        *,
        data_dir: Path | None = None,
        timeout: float = QUERY_TIMEOUT,
    ) -> None:
        if isinstance(own_registry_key, str):
            own_registry_key = parse_public_key(own_registry_key)
        self.own_address = own_address.with_user(None)
        self.own_registry_key = own_registry_key
        self.labs_path = data_dir / LABS_FILE if data_dir else None
        self.timeout = timeout
        self._own_session = own_session
        self._links: dict[tuple[str, int, str], LabLink] = {}
        self._lock = threading.Lock()
        self._connections: list[RealConnection] = []

    def _is_own(self, address: LabAddress) -> bool:
        own = self.own_address
        if address.realm != own.realm or address.port != own.port:
            return False
        local = {"127.0.0.1", "localhost", "::1"}
        return address.host == own.host or (address.host in local and own.host in local)

    def _link(self, address: LabAddress) -> LabLink:
        key = address.lab_key
        with self._lock:
            link = self._links.get(key)
            if link is not None:
                link.users += 1
                return link
        if self._is_own(address):
            if self.own_registry_key is None:
                raise LoginError(
                    "this viewer was started without --registry-key, so it cannot check "
                    "that the lab's registry is genuine; ask the lab's admin"
                )
            link = LabLink(address, self._own_session, self.own_registry_key, own=True)
        else:
            known = load_labs(self.labs_path, self.own_address.realm).get(key)
            if known is None:
                where = self.labs_path or "the viewer's data directory"
                raise LoginError(
                    f"this viewer does not know the lab {address.label}: its admin must add "
                    f"it, with its registry key, to {where} (keys are never trusted blindly)"
                )
            options = NetworkOptions(
                realm=address.realm, mode="client", connect=(address.endpoint,)
            )
            try:
                session = open_session(options, wait=3.0, quiet=True)
            except ConnectionError:
                raise LoginError(
                    f"no lab router answers at {address.host}:{address.port}"
                ) from None
            link = LabLink(address, session, known.registry_key, own=False)
        with self._lock:
            existing = self._links.get(key)
            if existing is not None:  # another browser opened it meanwhile: use theirs
                existing.users += 1
                if link.session is not self._own_session:
                    close_session(link.session)
                return existing
            link.users = 1
            self._links[key] = link
        return link

    def _unlink(self, link: LabLink) -> None:
        with self._lock:
            link.users -= 1
            if link.users > 0 or link.own:
                return
            self._links.pop(link.address.lab_key, None)
        link.close()

    def login(self, address: LabAddress, user: str, password: str, via: str = "") -> RealConnection:
        link = self._link(address)
        client = lab.LabClient(
            link.session, address.realm, link.registry_key, timeout=self.timeout, via=via
        )
        try:
            client.login(user, password)
        except lab.WrongCredentials:
            self._unlink(link)
            raise LoginError("wrong user name or password") from None
        except lab.RegistryKeyMismatch:
            self._unlink(link)
            raise LoginError(
                f"the registry answering at {address.label} is not the one this viewer trusts "
                "(its key differs): tell the lab's admin"
            ) from None
        except lab.RegistryUnreachable:
            self._unlink(link)
            raise LoginError(
                f"the lab's registry at {address.label} does not answer (is the lab running?)"
            ) from None
        except lab.LabError as exc:
            self._unlink(link)
            raise LoginError(str(_plain(exc, address))) from None
        connection = RealConnection(self, link, client, address.with_user(user))
        with self._lock:
            self._connections.append(connection)
        return connection

    def _closed(self, connection: RealConnection) -> None:
        with self._lock:
            if connection in self._connections:
                self._connections.remove(connection)
        self._unlink(connection.link)

    def close(self) -> None:
        """Log everyone out and close the other labs' sessions (the viewer is stopping)."""
        with self._lock:
            connections = list(self._connections)
        for connection in connections:
            connection.logout()
        with self._lock:
            links = list(self._links.values())
            self._links.clear()
        for link in links:
            link.close()


# --- one user's connection ----------------------------------------------------------------


@dataclass
class _Worldish:
    """A directory entry for a running world that no agent context announces (yet)."""

    world: str


@dataclass
class _Events:
    subscribers: dict[int, Callable[[LabEvent], None]] = field(default_factory=dict)
    next_id: int = 1


class RealConnection:
    """One browser user's session with one lab, over :class:`~common.client.LabClient`."""

    def __init__(
        self, connector: RealConnector, link: LabLink, client: lab.LabClient, address: LabAddress
    ) -> None:
        self.connector = connector
        self.link = link
        self.client = client
        self._address = address
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
        self._arenas: dict[str, ArenaLink] = {}  # joined agent contexts
        self._ctx_worlds: dict[str, str] = {}  # agent context -> its world (never changes)
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

    def _call(self, fn: Callable[[], Any]) -> Any:
        if self._closed.is_set():
            raise LabError("you are logged out of this lab")
        try:
            return fn()
        except lab.LabError as exc:
            raise _plain(exc, self._address) from None

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
                status.status if status.status in ("joined", "kicked") else "left"  # type: ignore[assignment]
            )
            self._queue.put(MemberEvent(ctx, status.user, kind, members, status.by, status.reason))
            self._queue.put(DirectoryEvent())

    # -- directory, contexts, chat

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
            except lab.LabError as exc:  # not answering yet: the next poll asks again
                log.debug("world of %s: %s", ctx, exc)
                return None
            world = self._ctx_worlds[ctx] = state.world
        return world

    def _live_worlds(self) -> set[str]:
        worlds: set[str] = set()
        realm = self._address.realm
        try:
            replies = self.link.session.liveliness().get(
                keys.alive_of_kind(realm, AliveKind.WORLD), timeout=2.0
            )
            for reply in replies:
                if reply.ok is None:
                    continue
                parsed = keys.parse_alive(realm, str(reply.ok.key_expr))
                if parsed is not None:
                    worlds.add(parsed[1])
        except zenoh.ZError as exc:
            log.debug("listing worlds: %s", exc)
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
        kind = summary.kind if summary is not None else "chat"
        world = summary.world if summary is not None else None
        if kind == "agent":
            # An agent context: chat and AgentEvents (queues, output) over one join.

            def on_room(event: RoomEvent) -> None:
                self._room_event(ctx, event)

            arena = self._call(lambda: ArenaLink(self.client, ctx, self._queue.put, on_room))
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

    def _arena(self, ctx: str) -> ArenaLink:
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

    def set_enabled(self, ctx: str, enabled: bool, agent: str | None = None) -> str:
        return self._arena(ctx).set_enabled(enabled, agent)

    # -- admin

    def list_accounts(self) -> list[Account]:
        users = self._call(self.client.list_users)
        return [
            Account(
                u.name,
                tuple(u.roles),
                tuple(sorted((scope, tuple(g)) for scope, g in u.grants.items())),
                u.online,
                u.failed_logins,
            )
            for u in users
        ]

    def add_account(self, user: str, password: str, roles: tuple[str, ...]) -> str:
        return str(self._call(lambda: self.client.add_user(user, password, roles)))

    def set_password(self, user: str, password: str) -> str:
        return str(self._call(lambda: self.client.set_password(user, password)))

    def remove_account(self, user: str) -> str:
        return str(self._call(lambda: self.client.remove_user(user)))

    def grant(self, user: str, grant: str, scope: str = "") -> str:
        return str(self._call(lambda: self.client.grant(user, grant, scope)))

    def ungrant(self, user: str, grant: str, scope: str = "") -> str:
        return str(self._call(lambda: self.client.ungrant(user, grant, scope)))

    def kick_from_server(self, user: str, reason: str = "") -> str:
        return str(self._call(lambda: self.client.kick_from_server(user, reason)))

    def rename_server(self, name: str) -> str:
        return str(self._call(lambda: self.client.rename_server(name)))

    def unlock_logins(self, user: str) -> str:
        return str(self._call(lambda: self.client.unlock_logins(user)))

    # -- the end

    def logout(self) -> None:
        """Leave every room, log out (presence goes), release worlds; safe to call twice."""
        if self._closed.is_set():
            return
        self._closed.set()
        with self._lock:
            self._events.subscribers.clear()
        self._queue.put(None)
        for feed in list(self._worlds.values()):
            self.link.release(feed.source)
        self._worlds.clear()
        self._arenas.clear()
        try:
            self.client.close()  # leaves rooms, logs out, undeclares the presence token
        except Exception:
            log.exception("logging %s out of %s", self.user, self._address.label)
        self.connector._closed(self)


# --- worlds ------------------------------------------------------------------------------


def _decode(raw: Any, kinds: Any) -> Message | None:
    try:
        return decode(raw, kinds)
    except MessageError as exc:
        log.warning("dropped a malformed world message: %s", exc)
        return None


def convert_snapshot(snap: WorldSnapshot) -> tuple[SceneLayout, tuple[str, ...]]:
    """The engine's snapshot as the view draws it, and the frame's object rows (ball order)."""
    obstacles: list[Obstacle] = []
    objects: dict[str, Ball] = {}
    for item in snap.items:
        shape = item.shape
        if item.category == "obstacle":
            if shape.kind == "circle":
                d = 2 * shape.radius
                obstacles.append(Obstacle(item.id, item.x, item.y, d, d, item.heading, round=True))
            else:
                xs = [p[0] for p in shape.points] or [0.0]
                ys = [p[1] for p in shape.points] or [0.0]
                w, h = max(xs) - min(xs), max(ys) - min(ys)
                cx, cy = (max(xs) + min(xs)) / 2, (max(ys) + min(ys)) / 2
                c, s = np.cos(item.heading), np.sin(item.heading)
                x, y = item.x + c * cx - s * cy, item.y + s * cx + c * cy
                obstacles.append(Obstacle(item.id, float(x), float(y), w, h, item.heading))
        elif item.category == "object":
            if shape.kind == "circle":
                r = shape.radius
            else:  # a crate or polygon: drawn as its bounding disc
                r = max((float(np.hypot(*p)) for p in shape.points), default=20.0)
            objects[item.id] = Ball(item.id, item.x, item.y, r)
    agents = tuple(a.id for a in snap.agents)
    object_rows = tuple(snap.rows[len(agents) :])
    balls = tuple(objects[o] for o in object_rows if o in objects)
    lights = tuple(Light(lt.id, lt.x, lt.y, lt.on) for lt in snap.lights)
    radius = snap.agents[0].radius if snap.agents else 27.5
    view = SceneLayout(
        world=snap.world,
        width=snap.width,
        height=snap.height,
        obstacles=tuple(obstacles),
        balls=balls,
        lights=lights,
        robots=agents,
        robot_radius=radius,
        version=snap.layout,
        offline=frozenset(a.id for a in snap.agents if not a.online),
    )
    return view, object_rows


class WorldWatch:
    """One world watched by the viewer, shared by every browser showing it."""

    def __init__(self, session: zenoh.Session, realm: str, world: str) -> None:
        self.session = session
        self.realm = realm
        self.world = world
        self.users = 0
        self.closed = False
        self.refetches = 0
        self._lock = threading.Lock()
        self._raw: Any = None
        self._raw_count = 0
        self._decoded_count = 0
        self._frame: SceneFrame | None = None
        self._snapshot: SceneLayout | None = None
        self._rows = 0
        self._want = threading.Event()
        self._first = threading.Event()
        self._error = ""
        self._sensors: dict[str, _SensorSub] = {}
        self._sub = session.declare_subscriber(keys.world_frame(realm, world), self._on_frame)
        self._thread = threading.Thread(target=self._refetcher, name=f"snap-{world}", daemon=True)
        self._want.set()
        self._thread.start()

    # Zenoh thread: keep the newest bytes, nothing else.
    def _on_frame(self, sample: zenoh.Sample) -> None:
        self._raw = sample.payload.to_bytes()
        self._raw_count += 1

    def ready(self, timeout: float = QUERY_TIMEOUT + 1.0) -> None:
        """Wait for the first snapshot; :class:`LabError` when the world does not answer."""
        if not self._first.wait(timeout) or self._snapshot is None:
            raise LabError(self._error or f"the world {self.world} does not answer (not running?)")

    def _refetcher(self) -> None:
        while not self.closed:
            self._want.wait(1.0)
            if self.closed or not self._want.is_set():
                continue
            self._want.clear()
            try:
                self.refetch()
            except LabError as exc:
                self._error = str(exc)
                log.info("snapshot of %s: %s", self.world, exc)
                if not self._first.is_set():
                    self._first.set()
                time.sleep(0.5)  # a world restarting: do not hammer it

    def refetch(self) -> None:
        reply = None
        for answer in self.session.get(
            keys.world_snapshot(self.realm, self.world), timeout=QUERY_TIMEOUT
        ):
            if answer.ok is not None:
                reply = _decode(answer.ok.payload, (WorldSnapshot, ErrorReply))
                break
        if reply is None:
            raise LabError(f"the world {self.world} does not answer (is its engine running?)")
        if isinstance(reply, ErrorReply):
            raise LabError(f"the world {self.world}: {reply.message}")
        assert isinstance(reply, WorldSnapshot)
        view, object_rows = convert_snapshot(reply)
        with self._lock:
            self._snapshot = view
            self._rows = len(view.robots) + len(object_rows)
            self._decoded_count = 0  # re-split the newest frame against the new layout
        self.refetches += 1
        self._first.set()

    def snapshot(self) -> SceneLayout:
        snap = self._snapshot
        if snap is None:
            raise LabError(f"the world {self.world} has not answered yet")
        return snap

    def latest(self) -> SceneFrame | None:
        count, raw = self._raw_count, self._raw
        if raw is None or count == self._decoded_count:
            return self._frame
        self._decoded_count = count
        wire = _decode(raw, WorldFrame)
        snap = self._snapshot
        if not isinstance(wire, WorldFrame) or snap is None:
            return self._frame
        if wire.layout != snap.version:
            self._want.set()  # an edit or a new map: everyone's view refetches
            return self._frame
        poses = wire.poses.to_numpy()
        if poses.shape != (self._rows, 3):
            self._want.set()
            return self._frame
        n = len(snap.robots)
        state = wire.agent_state.to_numpy()
        gripper = state[:, 2].astype(np.uint8) if state.ndim == 2 and len(state) == n else None
        if snap.offline:
            gripper = np.zeros(n, np.uint8) if gripper is None else gripper.copy()
            gripper[[i for i, a in enumerate(snap.robots) if a in snap.offline]] = OFFLINE
        self._frame = SceneFrame(
            seq=wire.tick,
            t=wire.sim_time,
            poses=np.ascontiguousarray(poses[:n], np.float32),
            gripper=gripper if gripper is not None else np.zeros(n, np.uint8),
            ball_xy=np.ascontiguousarray(poses[n:, :2], np.float32),
            lights_on=wire.lights.to_numpy().astype(np.bool_),
        )
        return self._frame

    def sensors(self, agent: str) -> RobotReadings | None:
        now = time.monotonic()
        with self._lock:
            for name in [n for n, s in self._sensors.items() if now - s.asked > SENSOR_IDLE_S]:
                self._sensors.pop(name).close()
            sub = self._sensors.get(agent)
            if sub is None:
                if self.closed or agent not in (self._snapshot.robots if self._snapshot else ()):
                    return None
                sub = _SensorSub(self.session, keys.agent_sensors(self.realm, self.world, agent))
                self._sensors[agent] = sub
            sub.asked = now
        return sub.latest(agent)

    def close(self) -> None:
        self.closed = True
        self._want.set()
        try:
            self._sub.undeclare()
        except zenoh.ZError as exc:
            log.debug("undeclare frames of %s: %s", self.world, exc)
        with self._lock:
            subs = list(self._sensors.values())
            self._sensors.clear()
        for sub in subs:
            sub.close()


class _SensorSub:
    """One robot's sensor stream, newest sample only (only the selected robot's is asked)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.asked = time.monotonic()
        self._raw: Any = None
        self._sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self._raw = sample.payload.to_bytes()

    def latest(self, agent: str) -> RobotReadings | None:
        raw = self._raw
        if raw is None:
            return None
        wire = _decode(raw, SensorSample)
        if not isinstance(wire, SensorSample) or wire.agent != agent:
            return None
        ir = np.zeros(8, np.float32)
        ambient = np.zeros(8, np.float32)
        ir[: min(8, len(wire.proximity))] = wire.proximity[:8]
        ambient[: min(8, len(wire.ambient))] = wire.ambient[:8]
        return RobotReadings(agent, wire.sim_time, ir, ambient)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except zenoh.ZError as exc:
            log.debug("undeclare sensors: %s", exc)


_SECTIONS = {"obstacle": "obstacles", "ball": "objects", "light": "lights", "agent": "agents"}
NEW_ITEM_PREFIX = {"obstacle": "box", "ball": "ball", "light": "light", "agent": "k"}


class UserWorld:
    """A world as one user sees it: the shared watch, plus edits sealed with their session."""

    def __init__(self, source: WorldWatch, connection: RealConnection) -> None:
        self.source = source  # the pump converts each shared frame once (see FramePump.tick)
        self._connection = connection

    @property
    def world(self) -> str:
        return self.source.world

    def snapshot(self) -> SceneLayout:
        return self.source.snapshot()

    def latest(self) -> SceneFrame | None:
        return self.source.latest()

    def sensors(self, agent: str) -> RobotReadings | None:
        return self.source.sensors(agent)

    def _ask(self, key: str, message: Message, what: str) -> EditResult:
        client = self._connection.client
        if "edit_map" not in self._connection.permissions:
            raise LabError(f"you may not {what}: it needs the 'edit_map' permission")
        session = client.session
        if session is None:
            raise LabError("you are logged out of this lab")
        reply = None
        for answer in self.source.session.get(
            key, payload=session.seal(key, message), timeout=QUERY_TIMEOUT
        ):
            if answer.ok is not None:
                reply = _decode(answer.ok.payload, (EditResult, ErrorReply))
                break
        if reply is None:
            raise LabError(f"the world {self.world} does not answer (is its engine running?)")
        if isinstance(reply, ErrorReply):
            if reply.code == "forbidden":
                raise LabError(f"you may not {what}: it needs the 'edit_map' permission")
            raise LabError(reply.message)
        assert isinstance(reply, EditResult)
        self.source._want.set()  # show the result at once, not at the next frame
        return reply

    def edit(self, edit: MapEdit) -> None:
        self._ask(
            keys.world_edit(self.source.realm, self.world),
            WorldEdit(op=to_wire_edit(edit, self.snapshot())),
            "edit the map",
        )

    def maps(self) -> list[str]:
        key = keys.world_map(self.source.realm, self.world)
        return list(self._ask(key, MapRequest(action="list"), "list maps").maps)

    def save_map(self, name: str) -> str:
        if not is_ident(name):
            raise LabError(f"{name!r} is not a map name: letters, digits, '_', '-', '.'")
        key = keys.world_map(self.source.realm, self.world)
        return self._ask(key, MapRequest(action="save", name=name), "save maps").detail

    def load_map(self, name: str) -> str:
        if not is_ident(name):
            raise LabError(f"{name!r} is not a map name")
        key = keys.world_map(self.source.realm, self.world)
        return self._ask(key, MapRequest(action="load", name=name), "load maps").detail


def fresh_id(kind: str, snap: SceneLayout) -> str:
    taken = {o.ident for o in snap.obstacles} | {b.ident for b in snap.balls}
    taken |= {lt.ident for lt in snap.lights} | set(snap.robots)
    prefix = NEW_ITEM_PREFIX.get(kind, "item")
    i = 1
    while f"{prefix}{i}" in taken:
        i += 1
    return f"{prefix}{i}"


def to_wire_edit(edit: MapEdit, snap: SceneLayout) -> Any:
    """A viewer edit as the engine's edit op; validated here so a browser cannot send junk."""
    for value in (edit.x, edit.y, edit.angle, edit.w, edit.h):
        if not np.isfinite(value):
            raise LabError("that edit has a number that is not finite")
    if edit.op == "resize":
        if edit.w <= 0 or edit.h <= 0:
            raise LabError("the arena's width and height must be positive")
        return ResizeArena(width=edit.w, height=edit.h)
    if edit.op in ("move", "delete") and not is_ident(edit.ident):
        raise LabError("select something first")
    if edit.op == "move":
        return MoveItem(id=edit.ident, x=edit.x, y=edit.y, heading=edit.angle)
    if edit.op == "delete":
        return RemoveItem(id=edit.ident)
    ident = edit.ident or fresh_id(edit.kind, snap)
    if not is_ident(ident):
        raise LabError(f"{ident!r} is not a valid name")
    heading_deg = float(np.degrees(edit.angle))
    entry: dict[str, Any]
    if edit.kind == "obstacle":
        entry = {"id": ident, "shape": "box", "width": edit.w or 100.0, "height": edit.h or 100.0}
        entry |= {"x": edit.x, "y": edit.y, "heading_deg": heading_deg}
    elif edit.kind == "ball":
        entry = {"id": ident, "shape": "circle", "radius": 20.0, "x": edit.x, "y": edit.y}
    elif edit.kind == "light":
        entry = {"id": ident, "x": edit.x, "y": edit.y}
    elif edit.kind == "agent":
        entry = {
            "id": ident,
            "type": "khepera",
            "x": edit.x,
            "y": edit.y,
            "heading_deg": heading_deg,
        }
    else:
        raise LabError(f"cannot add a {edit.kind}")
    return AddItem(section=_SECTIONS[edit.kind], entry=entry)  # type: ignore[arg-type]
