"""The worlds a viewer shows, over the engine's (or bridge's) world keys.

Worlds are watched once per lab and world (:class:`WorldWatch`), shared by
every browser: a short subscriber callback keeps only the newest frame's
bytes; the pump's ``latest()`` decodes it at most once per new frame; a frame
whose layout differs from the snapshot's wakes a thread that refetches the
snapshot (Zenoh queries never run inside Zenoh callbacks). Edits go through a
per-user :class:`UserWorld` that seals them with that user's session.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import zenoh

from common import keys
from common.ask import ask
from common.keys import is_ident
from common.lab_errors import NotAnswering
from common.messages import (
    AddItem,
    AgentStates,
    EditResult,
    MapRequest,
    Message,
    MessageError,
    MoveItem,
    RemoveItem,
    ResetAgent,
    ResizeArena,
    RobotTypeReply,
    RobotTypeRequest,
    SensorSample,
    WorldEdit,
    WorldFrame,
    WorldSnapshot,
    decode,
)
from common.messages.world import MAX_ROBOT_FILE_BYTES
from viewers.web import geometry as geo
from viewers.web.adapters import LabError
from viewers.web.arena_video import CameraFeed
from viewers.web.prepared_frame import OFFLINE
from viewers.web.world_feed import (
    Ball,
    Light,
    MapEdit,
    Obstacle,
    RobotReadings,
    SceneFrame,
    SceneLayout,
)

if TYPE_CHECKING:  # the connection makes a UserWorld; only its type is needed here
    from viewers.web.live import LiveConnection

log = logging.getLogger("wart.viewer.live")

QUERY_TIMEOUT = 5.0
DOES_NOT_ANSWER = (
    "the world {world} does not answer yet (its engine may still be starting, or be stopped)"
)
M = TypeVar("M", bound=Message)
SENSOR_IDLE_S = 5.0  # a robot's sensor subscription ends when nobody asked for it this long


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
        looks={look.type: geo.look_segments(look.segments, look.roles) for look in snap.looks},
        floor_lines=tuple(
            (tuple((float(x), float(y)) for x, y in line.points), line.width, line.colour)
            for line in snap.floor_lines
        ),
        robot_radii=(
            tuple(a.radius for a in snap.agents) if len({a.radius for a in snap.agents}) > 1 else ()
        ),
        version=snap.layout,
        offline=frozenset(a.id for a in snap.agents if not a.online),
        real=snap.kind == "real",
        robot_types={a.id: (a.type, tuple((n, r) for n, r in a.components)) for a in snap.agents},
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
        self._error: LabError | None = None  # why the last snapshot could not be had
        self._sensors: dict[str, _SensorSub] = {}
        self._camera: CameraFeed | None = None  # a real world's cameras, once asked for
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
            raise self._error or NotAnswering(DOES_NOT_ANSWER.format(world=self.world))

    def _refetcher(self) -> None:
        while not self.closed:
            self._want.wait(1.0)
            if self.closed or not self._want.is_set():
                continue
            self._want.clear()
            try:
                self.refetch()
            except LabError as exc:
                self._error = exc
                log.info("snapshot of %s: %s", self.world, exc)
                if not self._first.is_set():
                    self._first.set()
                time.sleep(0.5)  # a world restarting: do not hammer it

    def refetch(self) -> None:
        try:
            reply = ask(
                self.session,
                keys.world_snapshot(self.realm, self.world),
                None,
                WorldSnapshot,
                what=f"the world {self.world}",
                timeout=QUERY_TIMEOUT,
            )
        except LabError as exc:
            if exc.reply is None:
                raise NotAnswering(DOES_NOT_ANSWER.format(world=self.world)) from None
            raise LabError(str(exc)) from None  # "the world w: its words"
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

    def camera(self) -> CameraFeed | None:
        """A real world's cameras (subscribed on first ask); None for a simulated one."""
        snap = self._snapshot
        if snap is None or not snap.real or self.closed:
            return None
        with self._lock:
            if self._camera is None:
                self._camera = CameraFeed(self.session, self.realm, self.world)
            return self._camera

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
        states = AgentStates.unpack(wire.agent_state, n)
        gripper = None if states is None else states.fingers.astype(np.uint8)
        leds = np.zeros(n, np.uint8) if states is None else states.leds.astype(np.uint8)
        if snap.offline:
            gripper = np.zeros(n, np.uint8) if gripper is None else gripper.copy()
            gripper[[i for i, a in enumerate(snap.robots) if a in snap.offline]] = OFFLINE
        self._frame = SceneFrame(
            seq=wire.tick,
            t=wire.sim_time,
            poses=np.ascontiguousarray(poses[:n], np.float32),
            gripper=gripper if gripper is not None else np.zeros(n, np.uint8),
            leds=leds,
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
                sub = _SensorSub(
                    self.session,
                    keys.agent_sensors(self.realm, self.world, agent),
                    keys.agent_watch(self.realm, self.world, agent),
                )
                self._sensors[agent] = sub
            sub.asked = now
        return sub.latest(agent)

    def close(self) -> None:
        if self._camera is not None:
            self._camera.close()
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

    def __init__(self, session: zenoh.Session, key: str, watch: str) -> None:
        self.asked = time.monotonic()
        self._raw: Any = None
        self._sub = session.declare_subscriber(key, self._on)
        # ``watch``: the robot's agent/<a>/watch token, a big world's cue to publish.
        self._watch = session.liveliness().declare_token(watch)

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
        speeds = np.asarray(wire.speeds, np.float32)  # a real robot's: its odometry's
        return RobotReadings(agent, wire.sim_time, ir, ambient, speeds)

    def close(self) -> None:
        for handle in (self._sub, self._watch):
            try:
                handle.undeclare()
            except zenoh.ZError as exc:
                log.debug("undeclare sensors: %s", exc)


_SECTIONS = {"obstacle": "obstacles", "ball": "objects", "light": "lights", "agent": "agents"}
NEW_ITEM_PREFIX = {"obstacle": "box", "ball": "ball", "light": "light", "agent": "k"}


class UserWorld:
    """A world as one user sees it: the shared watch, plus edits sealed with their session."""

    def __init__(self, source: WorldWatch, connection: LiveConnection) -> None:
        self.source = source  # the pump converts each shared frame once (see FramePump.tick)
        self._connection = connection

    @property
    def world(self) -> str:
        return self.source.world

    def snapshot(self) -> SceneLayout:
        return self.source.snapshot()

    def camera(self) -> CameraFeed | None:
        return self.source.camera()

    def latest(self) -> SceneFrame | None:
        return self.source.latest()

    def sensors(self, agent: str) -> RobotReadings | None:
        return self.source.sensors(agent)

    def _ask(
        self, key: str, message: Message, what: str, *, needs_edit_map: bool = True
    ) -> EditResult:
        if needs_edit_map and "edit_map" not in self._connection.permissions:
            raise LabError(f"you may not {what}: it needs the 'edit_map' permission")
        reply = self._ask_world(key, message, EditResult, what, edit_map_refusal=needs_edit_map)
        self.source._want.set()  # show the result at once, not at the next frame
        return reply

    def _ask_world(
        self,
        key: str,
        message: Message,
        expected: type[M],
        what: str,
        *,
        edit_map_refusal: bool = True,
    ) -> M:
        """The world's answer to ``message`` sealed with my session, or a LabError in my
        words; ``edit_map_refusal``: a refusal means I lack 'edit_map'."""
        session = self._connection.client.session
        if session is None:
            raise LabError("you are logged out of this lab")
        try:
            return ask(
                self.source.session,
                key,
                message,
                expected,
                what=what,
                timeout=QUERY_TIMEOUT,
                seal=session.seal,
            )
        except LabError as exc:
            if exc.reply is None:
                raise NotAnswering(DOES_NOT_ANSWER.format(world=self.world)) from None
            if exc.reply.code == "forbidden" and edit_map_refusal:
                raise LabError(f"you may not {what}: it needs the 'edit_map' permission") from None
            raise LabError(exc.reply.message) from None

    def edit(self, edit: MapEdit) -> None:
        self._ask(
            keys.world_edit(self.source.realm, self.world),
            WorldEdit(op=to_wire_edit(edit, self.snapshot())),
            "edit the map",
        )

    def reset(self, agent: str) -> str:
        """The robot back at its start pose; the world checks I hold it (or may edit maps)."""
        if not is_ident(agent):
            raise LabError("choose a robot first")
        if self.snapshot().real:
            raise LabError(f"{self.world} is a real arena: put the robot back by hand")
        key = keys.world_edit(self.source.realm, self.world)
        message = WorldEdit(op=ResetAgent(id=agent))
        return self._ask(key, message, f"reset {agent}", needs_edit_map=False).detail

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

    # -- robot types (the robot builder; docs/ROBOTS.md)

    def _robots(self, request: RobotTypeRequest, what: str) -> RobotTypeReply:
        key = keys.world_robots(self.source.realm, self.world)
        return self._ask_world(key, request, RobotTypeReply, what)

    def robot_types(self) -> RobotTypeReply:
        return self._robots(RobotTypeRequest(action="list"), "list robot types")

    def robot_file(self, name: str) -> str:
        return self._robots(RobotTypeRequest(action="get", name=name), "read robot types").text

    def save_robot_type(self, text: str) -> tuple[str, str]:
        if "edit_map" not in self._connection.permissions:
            raise LabError("you may not save robot types: it needs the 'edit_map' permission")
        if len(text.encode("utf-8")) > MAX_ROBOT_FILE_BYTES:
            raise LabError(f"a robot file is at most {MAX_ROBOT_FILE_BYTES} bytes")
        reply = self._robots(RobotTypeRequest(action="save", text=text), "save robot types")
        self.source._want.set()
        return reply.detail, reply.name or ""


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
            "type": edit.robot_type,
            "x": edit.x,
            "y": edit.y,
            "heading_deg": heading_deg,
        }
    else:
        raise LabError(f"cannot add a {edit.kind}")
    # A robot or a ball goes to the free spot nearest where it was asked for (the world
    # finds it); a box goes where it is put.
    near = edit.kind in ("agent", "ball")
    return AddItem(section=_SECTIONS[edit.kind], entry=entry, nearest_free=near)  # type: ignore[arg-type]
