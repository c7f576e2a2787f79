"""Contexts on request: the one implementation behind ``wart host`` and ``wart up``.

A :class:`HostingService` answers ``host/<h>/spawn`` (start or stop an arena,
start or stop a chat room, ``host`` permission) and ``host/<h>/load`` (its
load, public), and publishes the load every few seconds. The processes it
starts are children of the host's :class:`~services.lab.supervisor.Supervisor`, so
they are restarted with backoff and stopped in order like every other service.

What differs between a host of a lab file and the one-machine lab's host
``local`` (where maps live, which accounts, which runner, the limits) is a
:class:`HostingPlan`; the rules (permissions, conflicts, limits, ownership)
are here once.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import msgspec
import psutil
import zenoh

from common import keys
from common.auth import Verifier, parse_public_key
from common.keys import AliveKind
from common.messages import ErrorReply, MessageError, OkReply, decode, encode
from common.messages.host import (
    ArenaInfo,
    ArenaReply,
    HostedState,
    HostLoad,
    LoadRequest,
    RoomInfo,
    RoomReply,
    SpawnArena,
    SpawnRoom,
    StopArena,
    StopRoom,
)
from common.revocations import RevocationFeed
from common.robots import registry as robot_registry
from common.service import RequestError, Service
from services.lab.lab_maps import map_with_robots
from services.lab.labfile import Limits
from services.lab.supervisor import Child, ChildSpec, Supervisor
from services.lab.wiring import (
    Wiring,
    arena_specs,
    chat_room_spec,
    plugin_context_spec,
    room_account,
)


@dataclass(frozen=True)
class HostingPlan:
    """Where a host's contexts come from: its wiring (maps, accounts, arenas) and limits."""

    wiring: Wiring
    registry_key: str  # hex, pinned by the Verifier of spawn requests
    limits: Limits
    max_rooms: int = 0  # 0: this host starts no chat rooms
    no_arenas_reason: str = ""  # why this host takes no arena at all ("" when it takes them)

    @property
    def realm(self) -> str:
        return self.wiring.realm

    @property
    def host(self) -> str:
        return self.wiring.host

    @property
    def state_dir(self) -> Path:
        """Arenas' generated maps go to STATE/arenas/."""
        return self.wiring.state_dir

    def no_arenas(self) -> str:
        return self.no_arenas_reason

    def resolve_map(self, name: str) -> Path:
        """A map by plain name; FileNotFoundError or ValueError when there is none."""
        return self.wiring.resolve_map(name)

    def arena_specs(self, world: str, map_path: Path, *, seed: int, owner: str) -> list[ChildSpec]:
        """The engine, then its agent context (named after the world, owned by ``owner``)."""
        return arena_specs(self.wiring, world, map_path, seed=seed, owner=owner)

    def context_specs(self, name: str, kind: str, args: list[str], owner: str) -> list[ChildSpec]:
        """A plugin's context type (``wart context KIND``), its params checked already."""
        if self.max_rooms <= 0:
            raise RequestError("unavailable", f"host {self.host} starts no contexts")
        return [plugin_context_spec(self.wiring, name, kind, args, detail=f"{kind} for {owner}")]

    def room_specs(self, name: str, title: str, owner: str) -> list[ChildSpec]:
        """The chat room's process, owned by ``owner`` (only when ``max_rooms`` > 0)."""
        if self.max_rooms <= 0:
            raise RequestError("unavailable", f"host {self.host} starts no chat rooms")
        return [
            chat_room_spec(
                self.wiring,
                name,
                title=title,
                account=room_account(self.host),
                owner=owner,
                detail=f"chat room for {owner}",
            )
        ]


@dataclass
class Hosted:
    """An arena or a room this host runs, with the children that make it."""

    info: ArenaInfo | RoomInfo
    children: list[Child] = field(default_factory=list)


class HostingService(Service):
    """Load reports and contexts on request for one host; the processes are the supervisor's."""

    kind = AliveKind.HOST

    def __init__(self, session: zenoh.Session, plan: HostingPlan, supervisor: Supervisor) -> None:
        super().__init__(session, plan.realm, plan.host)
        self.plan = plan
        self.supervisor = supervisor
        registry_key = parse_public_key(plan.registry_key)
        self.verifier = Verifier(registry_key, plan.realm)
        self._registry_key = registry_key
        self._feed: RevocationFeed | None = None
        self.arenas: dict[str, Hosted] = {}
        self.rooms: dict[str, Hosted] = {}
        self._lock = threading.Lock()
        self._spawn_lock = threading.Lock()  # one start at a time on a host
        self._load_thread: threading.Thread | None = None
        self._procs: dict[int, psutil.Process] = {}
        psutil.cpu_percent(None)  # the first reading is meaningless; start the interval now

    # -- lifecycle

    def on_start(self) -> None:
        self._feed = RevocationFeed(self.session, self.realm, self._registry_key, self.verifier)
        self.publisher = self.track(
            self.session.declare_publisher(keys.host_load(self.realm, self.ident))
        )
        self.serve(keys.host_spawn(self.realm, self.ident), self._on_spawn)
        # Not self.serve: a reply must carry this host's own key, or the answers of
        # several hosts to one `host/*/load` query are consolidated into one.
        self.track(
            self.session.declare_queryable(
                keys.host_load(self.realm, self.ident), self._on_load_query
            )
        )
        self._load_thread = threading.Thread(target=self._report, name="load", daemon=True)
        self._load_thread.start()

    def on_stop(self, timeout: float) -> None:
        if self._feed is not None:
            self._feed.close()
        if self._load_thread is not None:
            self._load_thread.join(timeout)

    def adopt(self, world: str, map_name: str, children: list[Child], robots: int) -> None:
        """Count a world the host started itself as one of its arenas (owner "lab")."""
        info = ArenaInfo(
            world=world,
            host=self.ident,
            map=map_name,
            robots=robots,
            owner="lab",
            state="running",
            started_at=time.time(),
        )
        with self._lock:
            self.arenas[world] = Hosted(info, children)

    # -- load

    def _measure(self, hosted: Hosted) -> tuple[HostedState, list[int], float, float]:
        """State, pids, resident MB and CPU % of one hosted context's processes."""
        rss = cpu = 0.0
        pids: list[int] = []
        state: HostedState = hosted.info.state
        for child in hosted.children:
            proc = child.process
            if proc is None:
                continue
            if proc.poll() is not None or child.restart_at is not None:
                state = "restarting"
                continue
            pids.append(proc.pid)
            try:
                p = self._procs.get(proc.pid)
                if p is None:  # keep the object: cpu_percent measures since its last call
                    p = self._procs[proc.pid] = psutil.Process(proc.pid)
                rss += p.memory_info().rss / 2**20
                cpu += p.cpu_percent(None)
            except psutil.Error:
                continue
        return state, pids, rss, cpu

    def load(self) -> HostLoad:
        mem = psutil.virtual_memory()
        cpu = psutil.cpu_percent(None)
        with self._lock:
            arenas_now = list(self.arenas.values())
            rooms_now = list(self.rooms.values())
        arenas = []
        for hosted in arenas_now:
            state, pids, rss, cpu_arena = self._measure(hosted)
            info = hosted.info
            assert isinstance(info, ArenaInfo)
            arenas.append(_with(info, state=state, pids=pids, rss_mb=round(rss, 1), cpu=cpu_arena))
        rooms = []
        for hosted in rooms_now:
            state = self._measure(hosted)[0]
            assert isinstance(hosted.info, RoomInfo)
            rooms.append(msgspec.structs.replace(hosted.info, state=state))
        reason = self._refusal(len(arenas), cpu, mem.available / 2**20)
        mine = {id(c) for hosted in [*arenas_now, *rooms_now] for c in hosted.children}
        services = [
            c.spec.name + ("" if c.process is not None and c.process.poll() is None else " (down)")
            for c in list(self.supervisor.children)
            if id(c) not in mine
        ]
        return HostLoad(
            host=self.ident,
            at=time.time(),
            cpus=psutil.cpu_count() or 1,
            cpu_percent=min(100.0, cpu),
            load1=os.getloadavg()[0],
            mem_total_mb=round(mem.total / 2**20, 1),
            mem_available_mb=round(mem.available / 2**20, 1),
            services=services,
            arenas=arenas,
            max_arenas=0 if self.plan.no_arenas() else self.plan.limits.max_arenas_per_host,
            accepting=not reason,
            reason=reason,
            rooms=rooms,
            max_rooms=self.plan.max_rooms,
        )

    def _refusal(self, count: int, cpu: float, available_mb: float) -> str:
        limits = self.plan.limits
        no_arenas = self.plan.no_arenas()
        if no_arenas:
            return no_arenas
        if count >= limits.max_arenas_per_host:
            return f"already runs {count} arenas (limits.max_arenas_per_host)"
        return self._busy(cpu, available_mb)

    def _busy(self, cpu: float, available_mb: float) -> str:
        limits = self.plan.limits
        if cpu > limits.max_cpu_percent:
            return f"CPU at {cpu:.0f} % (over limits.max_cpu_percent {limits.max_cpu_percent:.0f})"
        if available_mb < limits.min_free_memory_mb:
            return f"only {available_mb:.0f} MB free (limits.min_free_memory_mb)"
        return ""

    def _report(self) -> None:
        period = self.plan.limits.load_period_s
        while not self._stopped.wait(period):
            try:
                self.publisher.put(encode(self.load()))
            except Exception as exc:  # the session may be closing; the next round retries
                self.log.debug("load report: %s", exc)

    def _on_load_query(self, query: zenoh.Query) -> None:
        try:
            if query.payload is not None:
                decode(query.payload, LoadRequest)
            reply: HostLoad | ErrorReply = self.load()
        except MessageError as exc:
            reply = ErrorReply(code="bad_request", message=str(exc))
        except Exception as exc:
            self.log.exception("load report failed")
            reply = ErrorReply(code="internal", message=f"load report failed: {exc}")
        try:
            query.reply(keys.host_load(self.realm, self.ident), encode(reply))
        except Exception as exc:  # the querier may have gone away
            self.log.debug("could not reply with the load: %s", exc)

    # -- requests

    def _on_spawn(self, query: zenoh.Query) -> ArenaReply | RoomReply | OkReply:
        key = str(query.key_expr)
        principal, request = self.verifier.open(
            key, query.payload, (SpawnArena, StopArena, SpawnRoom, StopRoom)
        )
        if isinstance(request, StopArena):
            principal.require("host", "stop arenas")
            return self.stop_arena(request.world, by=principal.user)
        if isinstance(request, SpawnRoom):
            principal.require("host", "start chat rooms")
            return RoomReply(room=self.start_room(request, owner=principal.user))
        if isinstance(request, StopRoom):
            principal.require("host", "stop chat rooms")
            return self.stop_room(request.name, by=principal.user)
        principal.require("host", "start arenas")
        return ArenaReply(arena=self.start_arena(request, owner=principal.user))

    def _taken(self, what: str, name: str, *tokens: str) -> None:
        """Refuse a name some live world or context already has, here or on any host."""
        with self._lock:
            here = name in self.arenas or name in self.rooms
        watch = self.supervisor.watch
        if here or (watch is not None and any(watch.present(t) for t in tokens)):
            raise RequestError("conflict", f"the name {name} is taken: {what} by that name runs")

    def _start(
        self, table: dict[str, Hosted], name: str, hosted: Hosted, specs: list[ChildSpec]
    ) -> None:
        """Start a hosted context's children in order; undo it all if one does not come up."""
        with self._lock:
            table[name] = hosted
        for spec in specs:
            child = self.supervisor.add(spec)
            hosted.children.append(child)
            self.supervisor.spawn(child)
            if not self.supervisor.wait_ready(child):
                self._discard(table, name)
                raise RequestError(
                    "internal", f"{spec.name} did not come up on {self.ident}; see its log"
                )

    def start_arena(self, request: SpawnArena, owner: str) -> ArenaInfo:
        limits = self.plan.limits
        if request.robots is not None and request.robots > limits.max_robots_per_arena:
            raise RequestError(
                "bad_request",
                f"{request.robots} robots is over the lab's limit of {limits.max_robots_per_arena}",
            )
        with self._spawn_lock:
            self._taken(
                "a world or context",
                request.world,
                keys.alive(self.realm, AliveKind.WORLD, request.world),
                keys.alive(self.realm, AliveKind.CONTEXT, request.world),
            )
            reason = self.load().reason
            if reason:
                raise RequestError("unavailable", f"host {self.ident} takes no arena now: {reason}")
            try:
                map_path = self.plan.resolve_map(request.map)
            except (FileNotFoundError, ValueError) as exc:
                raise RequestError("not_found", str(exc)) from None
            robots = request.robots or 0
            if robots:
                map_path = map_with_robots(
                    map_path, robots, self.plan.state_dir / "arenas" / f"{request.world}.json"
                )
            info = ArenaInfo(
                world=request.world,
                host=self.ident,
                map=request.map,
                robots=robots,
                owner=owner,
                state="starting",
                started_at=time.time(),
            )
            hosted = Hosted(info)
            self.log.info("starting arena %s (%s) for %s", request.world, request.map, owner)
            specs = self.plan.arena_specs(request.world, map_path, seed=request.seed, owner=owner)
            self._start(self.arenas, request.world, hosted, specs)
            hosted.info = msgspec.structs.replace(info, state="running")
            return hosted.info

    def start_room(self, request: SpawnRoom, owner: str) -> RoomInfo:
        if self.plan.max_rooms <= 0:
            raise RequestError("unavailable", f"host {self.ident} starts no chat rooms")
        with self._spawn_lock:
            self._taken(
                "a context",
                request.name,
                keys.alive(self.realm, AliveKind.CONTEXT, request.name),
            )
            with self._lock:
                count = len(self.rooms)
            if count >= self.plan.max_rooms:
                raise RequestError(
                    "unavailable",
                    f"host {self.ident} already runs {count} chat rooms (its limit)",
                )
            mem = psutil.virtual_memory()
            busy = self._busy(psutil.cpu_percent(None), mem.available / 2**20)
            if busy:
                raise RequestError("unavailable", f"host {self.ident} takes no room now: {busy}")
            info = RoomInfo(
                name=request.name,
                host=self.ident,
                title=request.title or request.name,
                owner=owner,
                state="starting",
                started_at=time.time(),
            )
            hosted = Hosted(info)
            if request.kind == "chat":
                self.log.info("starting chat room %s for %s", request.name, owner)
                specs = self.plan.room_specs(request.name, info.title, owner)
            else:
                kind = robot_registry.default().contexts.get(request.kind)
                if kind is None:
                    known = ", ".join(["chat", *robot_registry.default().contexts])
                    raise RequestError(
                        "not_found",
                        f"host {self.ident} has no context type {request.kind!r} (it has: {known})",
                    )
                try:
                    args = robot_registry.context_arguments(kind, dict(request.params))
                except ValueError as exc:
                    raise RequestError("bad_request", f"{request.kind}: {exc}") from None
                info = msgspec.structs.replace(info, kind=request.kind)
                hosted = Hosted(info)
                self.log.info("starting %s %s for %s", request.kind, request.name, owner)
                specs = self.plan.context_specs(request.name, request.kind, args, owner)
            self._start(self.rooms, request.name, hosted, specs)
            hosted.info = msgspec.structs.replace(info, state="running")
            return hosted.info

    def stop_arena(self, world: str, by: str) -> OkReply:
        with self._lock:
            hosted = self.arenas.get(world)
        if hosted is None:
            raise RequestError("not_found", f"host {self.ident} runs no arena named {world}")
        if hosted.info.owner == "lab":
            raise RequestError("forbidden", f"{world} is part of the lab's own setup; it stays")
        self._discard(self.arenas, world)
        self.log.info("stopped arena %s for %s", world, by)
        return OkReply(detail=f"arena {world} stopped on {self.ident}")

    def stop_room(self, name: str, by: str) -> OkReply:
        with self._lock:
            hosted = self.rooms.get(name)
        if hosted is None:
            raise RequestError(
                "not_found", f"host {self.ident} runs no chat room named {name} started on request"
            )
        self._discard(self.rooms, name)
        self.log.info("stopped chat room %s for %s", name, by)
        return OkReply(detail=f"chat room {name} stopped on {self.ident}")

    def _discard(self, table: dict[str, Hosted], name: str) -> None:
        with self._lock:
            hosted = table.pop(name, None)
        if hosted is not None:
            for child in reversed(hosted.children):
                self.supervisor.stop_child(child)


def _with(
    info: ArenaInfo, *, state: HostedState, pids: list[int], rss_mb: float, cpu: float
) -> ArenaInfo:
    return msgspec.structs.replace(
        info, state=state, pids=pids, rss_mb=rss_mb, cpu_percent=round(cpu, 1)
    )
