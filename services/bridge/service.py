"""The Khepera bridge on the Zenoh network: real robots as the agents of a real world.

Same keys and messages as the Sim2D engine (docs/ARCHITECTURE.md), so the
agent context, the viewer and controllers cannot tell the two apart:

Publishes ``world/<w>/frame`` (WorldFrame: every robot's pose) every
``frame_interval``, and ``world/<w>/layout`` (WorldLayout) when its rows
change; ``agent/<a>/sensors`` (SensorSample) after every sensor round of
that robot, and then ``world/<w>/samples`` (a SampleBundle of that one
sample) if the robot is leased and someone subscribes;
``world/<w>/sensors`` (SensorBatch) while someone subscribes. Subscribes
``agent/*/cmd`` and ``world/<w>/cmds`` (AgentCommand, sealed or MACed, alone
or in a CommandBundle, or a swarm's MacCommandBundle, from the current lease
holder only) and
``agent/*/lease`` (Lease, sealed, ``lease``
permission), both checked by common.world.leases.LeaseBook exactly as the engine
does. Serves ``snapshot`` (arena, agents with their online state);
``edit`` and ``map`` answer ``bad_request`` (a real arena cannot be edited).
Token ``alive/world/<w>``.

A robot's pose is its odometry, corrected by the arena camera's sightings
when a camera tracks this world (``world/<w>/tracked``, common/tracking/
fusion.py): odometry alone drifts off the arena within a few runs. The
snapshot says where each pose comes from (``AgentInfo.pose_from``): a robot a
live camera lost is "not seen" and stays where it was last seen, never a guess
outside the arena.

Threads: one I/O thread per robot (KheperaRobot) owns its serial port;
Zenoh callbacks only check and queue commands on it (never wait on the
wire); the frame thread publishes frames and halts robots whose lease
ended; the scan thread (``--autodetect``) probes new ports.
"""

from __future__ import annotations

import functools
import math
import os
import re
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import zenoh

from common import keys
from common.auth import AuthError, Session, Verifier
from common.controller.actuators import apply_command
from common.keys import AliveKind
from common.messages import (
    AgentCommand,
    AgentInfo,
    Message,
    SensorBatch,
    SensorSample,
    TrackedPoses,
    WorldFrame,
    WorldSnapshot,
    decode,
    encode,
)
from common.service import RequestError
from common.tracking.fusion import PoseFusion
from common.world.leasemac import WorldBoxKeys, snapshot_with_identity
from common.world.leases import LeaseBook
from common.world.world_service import WorldService
from services.bridge import packing
from services.bridge.cameras import CAMERA_HUNG_S, ArenaCameras
from services.bridge.detect import candidate_ports, detect
from services.bridge.odometry import Pose
from services.bridge.robot import KheperaRobot, RobotOptions, RobotState

# Khepera I facts the snapshot carries (docs/KHEPERA_PROTOCOL.md "Body" and "Sensor placement").
KHEPERA_RADIUS_MM = 27.5
KHEPERA_LEDS = 2
KHEPERA_SPEED_LIMIT = 127
KHEPERA_PROXIMITY_MAX = 1023
KHEPERA_IR_POSES: tuple[tuple[float, float, float], ...] = tuple(
    (x, y, math.radians(deg))
    for x, y, deg in (
        (10, 24, 90),
        (19, 17, 45),
        (25, 6, 0),
        (25, -6, 0),
        (19, -17, -45),
        (10, -24, -90),
        (-24, -10, 180),
        (-24, 10, 180),
    )
)
ONLINE_COLOUR, OFFLINE_COLOUR, NOT_SEEN_COLOUR = "#2e86de", "#8a8a8a", "#c8c8c8"


@dataclass(frozen=True)
class RobotSpec:
    """A robot added by hand: its serial port and its agent id."""

    port: str
    agent: str
    pose: Pose | None = None  # where it stands in the arena at start (None: spread out)


@dataclass(frozen=True)
class BridgeSettings:
    robots: tuple[RobotSpec, ...] = ()
    autodetect: bool = False
    scan: tuple[str, ...] = ()  # extra paths / globs to probe (besides pyserial's list)
    system_ports: bool = True  # probe the ports pyserial lists too
    scan_interval: float = 5.0  # s between probes for new robots (0: only at start)
    bauds: tuple[int, ...] = (38400,)  # tried in order when probing
    arena: tuple[float, float] = (1000.0, 1000.0)  # mm
    robot: RobotOptions = field(default_factory=RobotOptions)
    frame_interval: float = 0.05  # s
    registry_key: bytes | None = None


def agent_id_for(port: str, taken: Sequence[str] = ()) -> str:
    """A stable agent id from a port path: its file name made an identifier, made unique."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "-", os.path.basename(port.rstrip("/")))[:56]
    base = base.lstrip("_.-") or "khepera"
    ident, n = base, 2
    while ident in taken:
        ident, n = f"{base}-{n}", n + 1
    return ident


@dataclass
class _Agent:
    id: str
    robot: KheperaRobot
    publisher: Any
    online: bool = False
    driving: tuple[str, bytes] | None = None  # (lease id, holder) of the lease last in force


class BridgeService(WorldService):
    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        world: str,
        settings: BridgeSettings,
        identity: Callable[[], Session] | None = None,
    ) -> None:
        """``identity`` returns the bridge's service session (None: no MAC leases)."""
        super().__init__(session, realm, world)
        self.settings = settings
        self.verifier = (
            Verifier(settings.registry_key, realm) if settings.registry_key is not None else None
        )
        self.box_keys = WorldBoxKeys(identity) if identity is not None else None
        self.leases = LeaseBook(realm, world, self.verifier, self.box_keys)
        self._agents: dict[str, _Agent] = {}  # insertion order = frame row order
        self._lock = threading.Lock()  # the agent table and layout
        self.layout = 0
        self._announced_layout = 0  # the layout the last WorldLayout said (publish thread)
        self._frames = 0
        self._t0 = time.monotonic()
        self._halt = threading.Event()
        self._threads: list[threading.Thread] = []
        w, h = settings.arena
        self.fusion = PoseFusion(
            w, h, radius_mm=KHEPERA_RADIUS_MM, camera_silent_after_s=CAMERA_HUNG_S
        )
        self.cameras = ArenaCameras(self.fusion)
        self._pose_from: dict[str, str] = {}  # agent -> where its shown pose comes from
        self._camera_said: bool | None = None

    # -- lifecycle

    def on_start(self) -> None:
        if self.verifier is None:
            self.log.warning("no --registry-key: every command and lease will be refused")
        self.declare_world_interface()
        self.subscribe(keys.world_tracked(self.realm, self.ident), self._on_tracked)
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive_of_kind(self.realm, AliveKind.CAMERA), self._on_camera, history=True
            )
        )
        n = len(self.settings.robots)
        for i, spec in enumerate(self.settings.robots):
            self.add_robot(spec.port, spec.agent, spec.pose or self._spread(i, n))
        self._thread("bridge-frames", self._frame_loop)
        if self.settings.autodetect:
            self._thread("bridge-scan", self._scan_loop)

    def _thread(self, name: str, target: Any) -> None:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        self._threads.append(thread)

    def on_stop(self, timeout: float) -> None:
        self.close_world_interface()
        self._halt.set()
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.1, deadline - time.monotonic()))
        with self._lock:
            agents = list(self._agents.values())
        # Each robot's stop() zeroes its motors before its port closes.
        for agent in agents:
            agent.robot.stop(max(0.1, deadline - time.monotonic()))
        for agent in agents:
            agent.publisher.undeclare()

    # -- robots

    def _spread(self, i: int, n: int) -> Pose:
        """Robots whose start pose nobody gave stand in a row across the arena's middle."""
        w, h = self.settings.arena
        return Pose(w * (i + 1) / (n + 1), h / 2, math.pi / 2)

    def add_robot(
        self, port: str, agent: str, pose: Pose | None = None, options: RobotOptions | None = None
    ) -> KheperaRobot:
        """Manual add (thesis 7.4.3): polled from now on, online when it answers B."""
        keys.check_ident("agent", agent)
        with self._lock:
            if agent in self._agents:
                raise ValueError(f"agent {agent} is already on {self._agents[agent].robot.port}")
        robot = KheperaRobot(port, options or self.settings.robot)
        robot.set_pose(pose or Pose(self.settings.arena[0] / 2, self.settings.arena[1] / 2))
        publisher = self.session.declare_publisher(
            keys.agent_sensors(self.realm, self.ident, agent)
        )
        entry = _Agent(agent, robot, publisher)
        robot.add_listener(functools.partial(self._on_state, entry))
        with self._lock:
            self._agents[agent] = entry
            self.layout += 1  # a new row: viewers refetch the snapshot
        robot.start()
        self.log.info("robot %s added on %s", agent, port)
        return robot

    def ports_in_use(self) -> set[str]:
        with self._lock:
            ports = [a.robot.port for a in self._agents.values()]
        return {os.path.realpath(p) for p in ports} | set(ports)

    def _scan_loop(self) -> None:
        interval = self.settings.scan_interval
        while not self._halt.is_set():
            try:
                self.scan_once()
            except Exception:  # a scan that failed is retried at the next interval
                self.log.exception("robot scan failed (will retry)")
            if interval <= 0 or self._halt.wait(interval):
                return

    def scan_once(self) -> list[str]:
        """Probe the candidate ports not in use; add every robot that answers. New agent ids."""
        used = self.ports_in_use()
        ports = [
            p
            for p in candidate_ports(self.settings.scan, system=self.settings.system_ports)
            if p not in used and os.path.realpath(p) not in used
        ]
        added = []
        for found in detect(ports, self.settings.bauds):
            if self._halt.is_set():
                break
            with self._lock:
                agent = agent_id_for(found.port, list(self._agents))
                n = len(self._agents)
            self.log.info(
                "found a Khepera on %s at %d baud (BIOS %s): agent %s",
                found.port,
                found.baud,
                found.version.bios,
                agent,
            )
            self.add_robot(
                found.port,
                agent,
                self._spread(n, n + 1),
                replace(self.settings.robot, baud=found.baud),
            )
            added.append(agent)
        return added

    def agent_ids(self) -> list[str]:
        with self._lock:
            return list(self._agents)

    def robot(self, agent: str) -> KheperaRobot | None:
        with self._lock:
            entry = self._agents.get(agent)
        return entry.robot if entry else None

    # -- robot I/O threads -> the network

    def _on_state(self, agent: _Agent, state: RobotState) -> None:
        """Called by the robot's I/O thread after each sensor round and on online changes."""
        pose = state.pose
        at = state.pose_at or time.time()
        self.fusion.odometry(agent.id, pose.x, pose.y, pose.heading, at=at)
        if state.online != agent.online:
            with self._lock:
                agent.online = state.online
                self.layout += 1  # the agent list's online states changed: refetch
            self.log.warning("robot %s is %s", agent.id, "online" if state.online else "OFFLINE")
        sample = self._sample(agent.id, state)
        if sample is None:
            return
        payload = encode(sample)
        agent.publisher.put(payload)
        # Robots are sampled each on its own serial line, so a bundle holds one
        # robot's round: the same key and type as the engine's, for the runner.
        if self.leases.in_force(agent.id) and self._samples_pub.matching_status.matching:
            self.publish_sample_bundle(sample.tick, {agent.id: payload})

    def _sample(self, agent: str, state: RobotState) -> SensorSample | None:
        return packing.sample(self.ident, agent, state, self._t0)

    # -- the network -> robots

    def _on_camera(self, sample: zenoh.Sample) -> None:
        parsed = keys.parse_alive(self.realm, str(sample.key_expr))
        if parsed is not None:
            self.cameras.presence(parsed[1], sample.kind == zenoh.SampleKind.PUT)

    def _on_tracked(self, sample: zenoh.Sample) -> None:
        """The arena camera's sightings: each corrects its robot's odometry."""
        seen = decode(sample.payload.to_bytes(), TrackedPoses)
        if seen.world != self.ident:
            return
        # Alive by when we heard it, not by its capture stamp: a busy camera host's frames
        # arrive a second or two late, and another machine's clock may be off by more.
        captured = self.cameras.frame(seen.camera, seen.captured_at, time.time(), seen.sent_at)
        if captured is None:
            return
        with self._lock:
            known = set(self._agents)
        for robot in seen.robots:
            if robot.agent in known:
                self.fusion.seen(
                    robot.agent, robot.x, robot.y, robot.heading, captured, seen.camera
                )

    def _shown_poses(self, agents: Sequence[_Agent], states: Sequence[RobotState]) -> list[Pose]:
        """Each robot's pose as the world shows it; a change of where poses come from
        bumps the layout (viewers refetch the snapshot that says it) and is logged once."""
        now = time.time()
        camera = self.fusion.camera_live(now)
        if camera != self._camera_said:
            self._camera_said = camera
            self.log.info(
                "camera over %s tracks its robots: poses from the camera"
                if camera
                else "no camera tracks %s (none, offline or not calibrated): poses from odometry",
                self.ident,
            )
        shown, changed = [], False
        for agent, state in zip(agents, states, strict=True):
            fused = self.fusion.pose(agent.id, now)
            source = fused.source if fused is not None else "odometry"
            if self._pose_from.get(agent.id) != source:
                if source == "not seen":
                    self.log.warning(
                        "%s is not seen by the camera: shown where it was last seen", agent.id
                    )
                elif source == "odometry" and camera:
                    age = self.fusion.sighting_age(agent.id, now)
                    if age is None:
                        self.log.warning(
                            "%s: the camera that saw it has gone and no other sees it: poses "
                            "from odometry",
                            agent.id,
                        )
                    else:  # its camera runs, but its frames come late (a loaded host)
                        self.log.warning(
                            "%s: its last sighting is %.1f s old (the camera's frames are "
                            "late): poses from odometry until a fresh one",
                            agent.id,
                            age,
                        )
                elif self._pose_from.get(agent.id) == "not seen":
                    self.log.info("%s is seen by the camera again", agent.id)
                self._pose_from[agent.id] = source
                changed = True
            shown.append(state.pose if fused is None else Pose(fused.x, fused.y, fused.heading))
        if changed:
            with self._lock:
                self.layout += 1
        return shown

    def _on_lease(self, sample: zenoh.Sample) -> None:
        self.leases.accept_lease(str(sample.key_expr), sample.payload)

    def halt_agent(self, agent: str) -> None:
        with self._lock:
            entry = self._agents.get(agent)
            if entry is not None:
                entry.driving = None
        if entry is not None:
            entry.robot.halt()

    def halt_all(self, engaged: bool) -> None:
        if not engaged:
            return  # robots stay at rest until a new slot's controller drives them
        with self._lock:
            agents = list(self._agents)
        for agent in agents:
            self.halt_agent(agent)

    def _obey(self, agent: str, command: AgentCommand) -> None:
        lease = self.leases.lease_of(agent)
        with self._lock:
            entry = self._agents.get(agent)
            if entry is not None and lease is not None:
                # Remember whose slot moved the robot, so its end halts it even if
                # the lease began and ended between two frame-thread checks.
                entry.driving = (lease.lease_id, lease.holder_session)
        if entry is None:
            raise AuthError("not_found", f"no robot {agent} on this bridge")
        self._send(entry, command)

    def _send(self, agent: _Agent, cmd: AgentCommand) -> None:
        """Queue the command's requests on the robot's I/O thread, in a fixed order; no wait.

        The robot logs and counts a request that fails (KheperaRobot.commands_failed).
        """
        if not apply_command(cmd, agent.robot):
            agent.robot.keepalive()  # an empty command only feeds the watchdog

    # -- frames, lease ends

    def _frame_loop(self) -> None:
        next_frame = time.monotonic()
        while not self._halt.is_set():
            try:
                self._check_leases()
                self._publish()
            except Exception:  # a bad frame must not stop the next ones
                self.log.exception("error publishing frame %d (kept running)", self._frames)
            next_frame += self.settings.frame_interval
            delay = next_frame - time.monotonic()
            if delay < -0.5:
                next_frame, delay = time.monotonic(), 0.0
            if delay > 0 and self._halt.wait(delay):
                return

    def _check_leases(self) -> None:
        """Halt a robot whose lease ended or passed to someone else (before its watchdog)."""
        now = time.time()
        with self._lock:
            agents = list(self._agents.values())
        for agent in agents:
            lease = self.leases.in_force(agent.id, now)
            current = (lease.lease_id, lease.holder_session) if lease else None
            with self._lock:
                ended, agent.driving = (
                    agent.driving if agent.driving not in (None, current) else None,
                    current,
                )
            if ended is not None:
                agent.robot.halt()
                self.log.info("lease %s on %s ended: robot halted", ended[0], agent.id)

    def _publish(self) -> None:
        with self._lock:
            agents = list(self._agents.values())
            layout = self.layout
        states = [a.robot.state() for a in agents]
        poses = self._shown_poses(agents, states)
        states = [replace(s, pose=p) for s, p in zip(states, poses, strict=True)]
        self._frames += 1
        self._frame_pub.put(encode(self.frame(states, layout)))
        if layout != self._announced_layout:
            self._announced_layout = layout
            self.announce_layout(layout)
        if agents and self._batch_pub.matching_status.matching:
            batch = self._batch(states, layout)
            if batch is not None:
                self._batch_pub.put(encode(batch))

    def frame(self, states: Sequence[RobotState], layout: int) -> WorldFrame:
        t = round(time.monotonic() - self._t0, 6)
        return packing.frame(self.ident, self._frames, t, states, layout)

    def _batch(self, states: Sequence[RobotState], layout: int) -> SensorBatch | None:
        t = round(time.monotonic() - self._t0, 6)
        return packing.batch(self.ident, self._frames, t, states, layout)

    # -- queries

    def snapshot(self) -> WorldSnapshot:
        with self._lock:
            agents = list(self._agents.values())
            layout = self.layout
        infos = []
        for a in agents:
            s = a.robot.state()
            fused = self.fusion.pose(a.id, time.time())
            pose = s.pose if fused is None else Pose(fused.x, fused.y, fused.heading)
            pose_from = self._pose_from.get(a.id, "odometry")
            colour = ONLINE_COLOUR if s.online else OFFLINE_COLOUR
            if s.online and pose_from == "not seen":
                colour = NOT_SEEN_COLOUR
            infos.append(
                AgentInfo(
                    id=a.id,
                    type="khepera",
                    radius=KHEPERA_RADIUS_MM,
                    colour=colour,
                    x=pose.x,
                    y=pose.y,
                    heading=pose.heading,
                    gripper=s.gripper is not None,
                    leds=KHEPERA_LEDS,
                    proximity_sensors=list(KHEPERA_IR_POSES),
                    proximity_max=KHEPERA_PROXIMITY_MAX,
                    speed_limit=KHEPERA_SPEED_LIMIT,
                    online=s.online,
                    pose_from=pose_from,  # type: ignore[arg-type]
                )
            )
        w, h = self.settings.arena
        return WorldSnapshot(
            world=self.ident,
            tick=self._frames,
            sim_time=round(time.monotonic() - self._t0, 6),
            layout=layout,
            tick_s=self.settings.frame_interval,
            seed=0,
            width=w,
            height=h,
            items=[],
            lights=[],
            agents=infos,
            rows=[a.id for a in agents],
            kind="real",
        )

    def _on_snapshot(self, query: zenoh.Query) -> Message:
        return snapshot_with_identity(self.snapshot(), self.box_keys)

    def _on_map(self, query: zenoh.Query) -> Message:
        return self._on_edit(query)

    def _on_robots(self, query: zenoh.Query) -> Message:
        return self._on_edit(query)  # its robots are the real ones: no robot types to add

    def _on_edit(self, query: zenoh.Query) -> Message:
        raise RequestError(
            "bad_request", f"{self.ident} is a real arena (Khepera bridge): it cannot be edited"
        )
