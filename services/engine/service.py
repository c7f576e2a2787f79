"""The engine on the Zenoh network: one world per process, stepped by one thread.

Zenoh callbacks stay short: they verify the envelope (and the lease, for
commands) and hand the work to the sim thread through a queue; requests that
need an answer (snapshot, edit, map) wait for the sim thread's result, at most
one tick. Only the sim thread touches the world (pymunk is not thread-safe).

Publishes: ``world/<w>/frame`` (WorldFrame) each tick while subscribed;
``world/<w>/layout`` (WorldLayout) when its rows change; ``agent/<a>/sensors``
(SensorSample) for agents someone subscribes to; ``world/<w>/samples``
(SampleBundle: every leased agent's sample) and ``world/<w>/sensors``
(SensorBatch) when someone subscribes. Subscribes: ``agent/*/cmd`` and
``world/<w>/cmds`` (AgentCommand, sealed or MACed, alone or in a
CommandBundle, or a swarm's MacCommandBundle; holder of the current lease
only) and ``agent/*/lease`` (Lease, sealed, ``lease`` permission). Serves: ``snapshot`` (anyone),
``edit`` and ``map`` (sealed, ``edit_map``). Token: ``alive/world/<w>``.

With an identity (``--user/--identity``, a service account with ``world``)
the snapshot carries its registry-signed token; contexts then seal each
lease's MAC key to it and commands are MacCommands (common/world/leasemac.py).
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from common import keys
from common.auth import Session, Verifier
from common.controller.actuators import apply_command
from common.messages import (
    AgentCommand,
    ErrorReply,
    Lease,
    Message,
    OkReply,
    encode,
)
from common.service import RequestError
from common.sim2d import maps, wander
from common.sim2d.drives import DEFAULT_DRIVE
from common.sim2d.world import EditError, World
from common.worker import Worker
from common.world import packing
from common.world.leasemac import WorldBoxKeys, snapshot_with_identity
from common.world.leases import LeaseBook
from common.world.world_service import WorldService
from services.engine.edits import EngineEdits
from services.engine.pace import PaceWatch

_FAST_PUBLISH_S = 0.02  # with --fast, publish at most 50 times a wall second
# Worlds of up to this many robots declare every robot's sensor publisher at
# start; bigger ones only those watched or leased (EngineSettings.streams_up_front).
STREAMS_UP_FRONT = 1000
# Publishers a world past streams_up_front declares for watchers (leased robots
# always get theirs): each is declared on the sim thread, and a client declaring
# a token for every robot would otherwise stall the world for as long as
# declaring them all takes (35 s at 10,000).
WATCHED_STREAMS_MAX = 256
# Robots from which declaring their sensor publishers is logged as it goes.
_SAY_PUBLISHERS_FROM = 1000
_PROGRESS_EVERY_S = 3.0


class _Progress:
    """Log lines for a long declaration: at the start, every few seconds, at the end."""

    def __init__(self, log: Any, total: int) -> None:
        self.log = log
        self.total = total
        self.started = self.said = time.monotonic()
        log.info("declaring the sensor publishers of %d robots (a few seconds a thousand)", total)

    def at(self, done: int) -> None:
        now = time.monotonic()
        if now - self.said >= _PROGRESS_EVERY_S:
            self.said = now
            self.log.info("sensor publishers: %d of %d declared", done, self.total)

    def done(self) -> None:
        self.log.info(
            "sensor publishers: all %d declared in %.1f s",
            self.total,
            time.monotonic() - self.started,
        )


@dataclass(frozen=True)
class EngineSettings:
    tick_s: float = 0.02
    speed: float = 1.0  # times real time
    fast: bool = False  # as fast as possible
    watchdog_s: float = 0.3
    maps_dir: Path = Path("maps")
    seed: int = 0
    registry_key: bytes | None = None
    wander: bool = False  # robots nobody commands avoid obstacles on their own (wander.py)
    # The --map the world started from: live edits are journalled against it (in
    # maps_dir) and replayed when the engine restarts on the same map. "" = no journal.
    base_map: str = ""
    # Threads of the sim thread's kernels (World.threads, World.physics_threads); kept
    # when a map is loaded on request.
    threads: int = 1
    physics_threads: int = 1
    drive: str = DEFAULT_DRIVE  # World.drive, kept when a map is loaded on request
    # Worlds of more robots declare a robot's sensor publisher only once someone
    # watches it (keys.agent_watch) or it is leased: Zenoh's cost per publisher
    # grows with their number (10,000 took 35 s, docs/OPERATIONS.md "Swarms").
    streams_up_front: int = STREAMS_UP_FRONT
    watched_streams_max: int = WATCHED_STREAMS_MAX  # of those declared for watchers


@dataclass(frozen=True)
class _Stream:
    """An agent someone started (or stopped) watching, or one just leased."""

    agent: str
    watched: bool | None  # None: leased


@dataclass
class _Command:
    agent: str
    command: AgentCommand
    received: float  # monotonic


class EngineService(WorldService):
    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        world: World,
        settings: EngineSettings,
        identity: Callable[[], Session] | None = None,
    ) -> None:
        """``identity`` returns the world's service session (None: no MAC leases)."""
        super().__init__(session, realm, world.name)
        self.world = world
        self.settings = settings
        self.verifier = (
            Verifier(settings.registry_key, realm) if settings.registry_key is not None else None
        )
        self._work: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.box_keys = WorldBoxKeys(identity) if identity is not None else None
        self.leases = LeaseBook(realm, world.name, self.verifier, self.box_keys)
        self._last_cmd: dict[str, float] = {}
        self._estopped = False  # the arena's emergency stop: robots do not even wander
        self._wander_layout = -1
        self._wanderers = np.zeros(0, bool)
        self._worker = Worker(self._run, f"sim-{self.ident}")
        self._agent_pubs: dict[str, Any] = {}
        self._matched: set[str] = set()
        # Agents whose sensors someone watches (their agent/<a>/watch tokens) or
        # that were leased: in a world past streams_up_front, the only ones with
        # a publisher. Sim thread only.
        self._watched: set[str] = set()
        self._leased: set[str] = set()
        self._on_demand = False
        self._rows_of: tuple[World, int] | None = None
        self._rows: set[str] = set()
        self._match_lock = threading.Lock()
        self.ticks_late = 0
        # Whether the world keeps the asked pace, said in the log when it does not.
        self.pace = PaceWatch(None if settings.fast else settings.speed, self._describe)
        # Edits, resets, robot types and maps: run on the sim thread, journalled.
        self.edits = EngineEdits(
            ident=self.ident,
            maps_dir=settings.maps_dir,
            load_map=self._load_map,
            verifier=self.verifier,
            leases=self.leases,
            current_world=lambda: self.world,
            in_sim=self._in_sim,
            use_world=self._use_world,
            log=self.log,
        )
        if settings.base_map:
            self.world = self.edits.replay_journal(settings.base_map, self.world)

    # -- lifecycle

    def on_start(self) -> None:
        if self.verifier is None:
            self.log.warning("no --registry-key: every command, lease and edit will be refused")
        self.declare_world_interface()
        # History: tokens declared before this engine started count too.
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.agent_watch_all(self.realm, self.ident), self._on_watch, history=True
            )
        )
        self._declare_agent_publishers()
        self._worker.start()

    def on_stop(self, timeout: float) -> None:
        self.close_world_interface()
        self._worker.stop(timeout)
        for pub in self._agent_pubs.values():
            pub.undeclare()
        self._agent_pubs.clear()

    # -- per-agent sensor publishers, only used when someone listens

    def _on_watch(self, sample: zenoh.Sample) -> None:
        agent = keys.parse_agent_key(self.realm, self.ident, str(sample.key_expr))
        if agent is not None:
            self._work.put(_Stream(agent, sample.kind == zenoh.SampleKind.PUT))

    def _stream(self, item: _Stream) -> None:
        """Sim thread: note who is watched or leased; declare what is now wanted."""
        if item.watched and item.agent not in self._agent_rows():
            # Not a robot of this world: a stale or hostile token. Dropped here, so
            # that a flood of them neither grows the set nor redoes the declarations.
            return
        if item.watched is None:
            self._leased.add(item.agent)
        elif item.watched:
            if (
                self._on_demand
                and item.agent not in self._agent_pubs
                and len(self._agent_pubs) >= self.settings.watched_streams_max
            ):
                self.log.warning(
                    "%s is watched, but %d robots' samples are published on demand "
                    "already (the most): not published; it is if leased",
                    item.agent,
                    len(self._agent_pubs),
                )
                return
            self._watched.add(item.agent)
        else:
            # Its publisher stays: a robot watched once is likely watched again,
            # and an unmatched publisher costs nothing a tick.
            self._watched.discard(item.agent)
            return
        if self._on_demand and item.agent not in self._agent_pubs:
            self._declare_agent_publishers()
            if item.agent in self._agent_pubs:
                self.log.info(
                    "%s's sensor samples published from now on (%s)",
                    item.agent,
                    "leased" if item.watched is None else "someone watches it",
                )

    def _agent_rows(self) -> set[str]:
        """The world's robots by name, rebuilt when its layout changes (sim thread)."""
        world = self.world
        if self._rows_of != (world, world.layout):
            self._rows_of = (world, world.layout)
            self._rows = {a.id for a in world.agents}
        return self._rows

    def _declare_agent_publishers(self) -> None:
        present = self._agent_rows()
        on_demand = len(present) > self.settings.streams_up_front
        if on_demand and not self._on_demand:
            self.log.info(
                "%d robots, more than --streams-up-front %d: a robot's sensor publisher "
                "is declared when someone watches it or it is leased",
                len(present),
                self.settings.streams_up_front,
            )
        self._on_demand = on_demand
        wanted = present & (self._watched | self._leased) if on_demand else present
        for agent in set(self._agent_pubs) - present:
            self._agent_pubs.pop(agent).undeclare()
            with self._match_lock:
                self._matched.discard(agent)
        todo = sorted(wanted - set(self._agent_pubs))
        # Zenoh's cost per publisher grows with their number: 10,000 took 35 s
        # here (docs/OPERATIONS.md, "Swarms"), so declaring thousands is said as it goes.
        progress = _Progress(self.log, len(todo)) if len(todo) >= _SAY_PUBLISHERS_FROM else None
        for done, agent in enumerate(todo):
            if progress is not None:
                progress.at(done)
            pub = self.session.declare_publisher(
                keys.agent_sensors(self.realm, self.ident, agent), express=True
            )

            def on_match(status: Any, agent: str = agent) -> None:
                with self._match_lock:
                    if status.matching:
                        self._matched.add(agent)
                    else:
                        self._matched.discard(agent)

            pub.declare_matching_listener(on_match)
            # zenoh's stubs type matching_status as a bool; it is a MatchingStatus.
            status: Any = pub.matching_status
            if status.matching:
                with self._match_lock:
                    self._matched.add(agent)
            self._agent_pubs[agent] = pub
        if progress is not None:
            progress.done()

    # -- callbacks (Zenoh threads): verify, then queue

    def _on_lease(self, sample: zenoh.Sample) -> None:
        lease = self.leases.accept_lease(str(sample.key_expr), sample.payload)
        # A leased robot gets its sensor publisher, watched or not (_stream).
        self._work.put(_Stream(lease.agent, None))

    def lease_of(self, agent: str) -> Lease | None:
        return self.leases.lease_of(agent)

    @property
    def commands_accepted(self) -> int:
        return self.leases.commands_accepted

    @property
    def commands_refused(self) -> int:
        return self.leases.commands_refused

    def halt_agent(self, agent: str) -> None:
        stop = AgentCommand(agent=agent, speeds=(0, 0))
        self._work.put(_Command(agent, stop, time.monotonic()))

    def halt_all(self, engaged: bool) -> None:
        def apply(world: World) -> Message:
            self._estopped = engaged
            if engaged:
                world.set_speeds_all(np.zeros_like(world.cmd))
                self._last_cmd.clear()
            return OkReply()

        # Between two ticks, like a command; nobody waits for the reply.
        self._work.put((apply, Future()))

    def _obey(self, agent: str, command: AgentCommand) -> None:
        self._work.put(_Command(agent, command, time.monotonic()))

    def _in_sim(self, fn: Callable[[World], Message], timeout: float = 5.0) -> Message:
        """Run ``fn`` on the sim thread between ticks and return its reply."""
        future: Future[Message] = Future()
        self._work.put((fn, future))
        try:
            return future.result(timeout)
        except TimeoutError:
            raise RequestError("unavailable", "the simulation did not answer in time") from None

    def _on_snapshot(self, query: zenoh.Query) -> Message:
        snap = self._in_sim(packing.snapshot)
        return snapshot_with_identity(snap, self.box_keys)

    def _on_edit(self, query: zenoh.Query) -> Message:
        return self.edits.on_edit(query)

    def _on_map(self, query: zenoh.Query) -> Message:
        return self.edits.on_map(query)

    def _on_robots(self, query: zenoh.Query) -> Message:
        return self.edits.on_robots(query)

    @property
    def replayed_edits(self) -> int:
        return self.edits.replayed_edits

    def _load_map(self, path: Path) -> World:
        """A map file as this engine's world: its name, seed, tick and thread counts."""
        settings = self.settings
        return maps.load_map(
            path,
            name=self.ident,
            seed=settings.seed,
            tick_s=settings.tick_s,
            threads=settings.threads,
            physics_threads=settings.physics_threads,
            drive=settings.drive,
        )

    def _use_world(self, world: World) -> None:
        """Sim thread: a map loaded on request is the world stepped from now on."""
        self.world = world
        self._last_cmd.clear()
        self._declare_agent_publishers()

    # -- the sim thread

    def _drain(self) -> None:
        while True:
            try:
                item = self._work.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, _Command):
                self._apply(item)
                continue
            if isinstance(item, _Stream):
                self._stream(item)
                continue
            fn, future = item
            # Errors become reply messages here, never exceptions handed across
            # threads: a re-raised exception's traceback would keep the Zenoh
            # query alive (and its final reply unsent) until garbage collection.
            try:
                reply = fn(self.world)
            except RequestError as exc:
                reply = ErrorReply(code=exc.code, message=exc.message)
            except Exception:
                self.log.exception("error serving a request (kept running)")
                reply = ErrorReply(code="internal", message="internal error; see the engine log")
            future.set_result(reply)

    def _apply(self, item: _Command) -> None:
        world = self.world
        try:
            slot = world.agent_slot(item.agent)
        except KeyError:
            return
        try:
            apply_command(item.command, world.actuators(slot))
        except EditError as exc:
            self.log.info("command to %s partly ignored: %s", item.agent, exc)
        self._last_cmd[item.agent] = item.received

    def _wander(self) -> None:
        """Undriven robots with the Khepera's IR layout run the built-in avoidance rule."""
        world = self.world
        if self._wander_layout != world.layout:  # which robots can wander changes with edits
            self._wander_layout = world.layout
            self._wanderers = np.array(
                [len(a.spec.proximity.poses) == len(wander.WEIGHTS) for a in world.agents], bool
            )
        if not self._wanderers.any() or world.proximity.shape[1] < len(wander.WEIGHTS):
            return
        mask = self._wanderers.copy()
        for agent in self._last_cmd:  # a controller drives it: leave its command alone
            with contextlib.suppress(KeyError):
                mask[world.agent_slot(agent)] = False
        speeds = world.cmd.astype(np.float64)
        speeds[mask] = wander.braitenberg(world.proximity[mask])
        world.set_speeds_all(speeds)

    def _watchdog(self) -> None:
        """A robot whose commands stopped arriving stops (like the real robot's bridge)."""
        now = time.monotonic()
        for agent, last in list(self._last_cmd.items()):
            if now - last > self.settings.watchdog_s:
                del self._last_cmd[agent]
                with contextlib.suppress(KeyError):
                    self.world.set_speeds(self.world.agent_slot(agent), 0, 0)
                self.log.info(
                    "watchdog: no command for %s in %.0f ms, stopped it",
                    agent,
                    self.settings.watchdog_s * 1000,
                )

    def _publish(self) -> None:
        world = self.world
        # Samples first: controllers react to them; viewers draw the frame at their own pace.
        # The frame (and the sensor batch) are built before the samples' put and only put
        # after it: work right after a put delays it, since on two cores Zenoh's I/O thread
        # waits for the core this thread holds (the sample leg was 0.28 ms longer than a
        # plain Zenoh peer's with the frame built after it; docs/BENCHMARKS.md).
        # Nobody watching the world (a headless swarm): no frame to build (0.4 ms
        # a tick at 10,000 robots, and its encoding).
        frame = encode(packing.frame(world)) if self._frame_pub.matching_status.matching else None
        batch = encode(packing.batch(world)) if self._batch_pub.matching_status.matching else None
        with self._match_lock:
            listening = set(self._matched)
        bundled = (
            self.leases.agents_in_force() if self._samples_pub.matching_status.matching else []
        )
        agents, slots = [], []
        for agent in sorted(listening.union(bundled)):
            try:
                slots.append(world.agent_slot(agent))
            except KeyError:
                continue
            agents.append(agent)
        if agents:
            encoded = dict(zip(agents, map(encode, packing.samples(world, slots)), strict=True))
            if bundled:
                inside = {a: encoded[a] for a in bundled if a in encoded}
                self.publish_sample_bundle(world.tick, inside)
            for agent in listening:
                pub = self._agent_pubs.get(agent)
                payload = encoded.get(agent)
                if pub is not None and payload is not None:
                    pub.put(payload)
        if frame is not None:
            self._frame_pub.put(frame)
        if batch is not None:
            self._batch_pub.put(batch)

    def _describe(self) -> str:
        world = self.world
        return f"world {world.name} ({len(world.agents)} robots, {world.drive} drive)"

    def _run(self) -> None:
        settings = self.settings
        period = 0.0 if settings.fast else settings.tick_s / settings.speed
        next_tick = time.monotonic()
        last_publish = 0.0
        layout = self.world.layout
        while not self._worker.stopping.is_set():
            try:
                self._drain()
                self._watchdog()
                if settings.wander and not self._estopped:
                    self._wander()
                self.world.step()
                if self.world.layout != layout:
                    layout = self.world.layout
                    self._declare_agent_publishers()
                    self.announce_layout(layout)
                now = time.monotonic()
                if not settings.fast or now - last_publish >= _FAST_PUBLISH_S:
                    last_publish = now
                    self._publish()
                report = self.pace.tick(self.world.sim_time)
                if report is not None:
                    (self.log.warning if report.level == "warning" else self.log.info)(
                        "%s", report.text
                    )
            except Exception:
                self.log.exception("error in tick %d (kept running)", self.world.tick)
            if settings.fast:
                continue
            next_tick += period
            delay = next_tick - time.monotonic()
            if delay > 0:
                self._worker.wait(delay)
            elif delay < -0.5:  # far behind (a stall): do not try to catch up in a burst
                self.ticks_late += 1
                next_tick = time.monotonic()
