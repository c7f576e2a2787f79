"""Wire types of worlds (Sim2D engines, Khepera bridges): frames, sensors, commands, leases, edits.

Units: mm, radians, seconds (docs/ARCHITECTURE.md section 6). Sensor values
are the robot type's raw units (Khepera: proximity 0..1023, ambient ~500 dark).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from common.messages.auth import SessionId, SignedToken
from common.messages.base import Bytes32, Ident, Message, NonNegInt, PackedArray, ShortText

Speed = Annotated[int, msgspec.Meta(ge=-32768, le=32767)]
Counter = Annotated[int, msgspec.Meta(ge=-(2**31), le=2**31 - 1)]
Byte = Annotated[int, msgspec.Meta(ge=0, le=255)]
Millimetres = Annotated[float, msgspec.Meta(ge=-1e7, le=1e7)]
Positive = Annotated[float, msgspec.Meta(gt=0.0, le=1e7)]


# K (32 bytes) in a SealedBox: 32 bytes of ephemeral public key + 16 of MAC + K.
SealedKey = Annotated[bytes, msgspec.Meta(min_length=80, max_length=80)]


class GripperReading(msgspec.Struct, frozen=True, kw_only=True):
    """The gripper turret as its protocol exposes it."""

    arm: Byte  # 165 up .. 255 down (Khepera)
    fingers: Literal["open", "closed", "holding"]
    presence: Byte  # object-presence barrier: 255 something between the fingers
    resistivity: Byte  # of the held object; 255 when nothing is held


PartName = Annotated[str, msgspec.Meta(pattern=r"^[a-z][a-z0-9_]{0,31}$")]
PartReading = Annotated[list[Counter], msgspec.Meta(max_length=64)]
Parts = Annotated[dict[PartName, PartReading], msgspec.Meta(max_length=32)]


class SensorSample(Message, frozen=True):
    """One agent's readings at one tick (``agent/<agent>/sensors``).

    ``parts``: the readings of the robot file's batched sensors (floor, range
    finder, bumper, a plugin's) by their names in the file; empty for a robot
    without any (an older reader ignores the field).
    """

    world: Ident
    agent: Ident
    tick: NonNegInt
    sim_time: float
    proximity: list[int]
    ambient: list[int]
    counters: tuple[int, int]  # pulses
    speeds: tuple[int, int]  # the type's speed unit (Khepera: pulses per 10 ms)
    leds: list[int]
    gripper: GripperReading | None = None
    parts: Parts = msgspec.field(default_factory=dict)


class SensorBatch(Message, frozen=True):
    """Every agent's readings in one message (``world/<world>/sensors``).

    Rows follow ``WorldSnapshot.agents``; cheaper than 1,000 per-agent puts.
    """

    world: Ident
    tick: NonNegInt
    sim_time: float
    layout: NonNegInt
    proximity: PackedArray  # uint16 (agents, 8)
    ambient: PackedArray  # uint16 (agents, 8)
    counters: PackedArray  # int32 (agents, 2)


MAX_BUNDLED = 1024
"""The most samples or commands one bundle carries (a runner drives at most tens of robots)."""


class SampleBundle(Message, frozen=True):
    """The newest SensorSample of several agents in one message (``world/<world>/samples``).

    A world puts one per tick holding every agent under a lease in force (the
    Khepera bridge: one per robot's sensor round), while someone subscribes.
    A process that drives many robots (the runner) receives one message per
    tick instead of one per robot: on a loaded host, Zenoh's per-message cost,
    not the payload, is what delays a burst of 20 samples.

    ``samples[i]`` is ``agents[i]``'s encoded SensorSample, left undecoded
    (msgspec Raw) so each reader decodes only the agents it drives.
    """

    world: Ident
    tick: NonNegInt
    agents: Annotated[list[Ident], msgspec.Meta(max_length=MAX_BUNDLED)]
    samples: Annotated[list[msgspec.Raw], msgspec.Meta(max_length=MAX_BUNDLED)]


class BundledCommand(msgspec.Struct, frozen=True, array_like=True):
    """One agent's command inside a CommandBundle."""

    agent: Ident
    payload: Annotated[bytes, msgspec.Meta(max_length=4096)]
    """Exactly what would be put on ``agent/<agent>/cmd``: an AuthEnvelope or a MacCommand."""


class CommandBundle(Message, frozen=True):
    """Several agents' commands in one message (``world/<world>/cmds``).

    Each payload is checked as if it had been put on its agent's own ``cmd``
    key (the signature or MAC covers that key expression): the bundle adds no
    authority, only saves messages. A refused item does not affect the others.
    """

    commands: Annotated[list[BundledCommand], msgspec.Meta(max_length=MAX_BUNDLED)]


# One command of a MacCommandBundle, as its bytes travel and are MACed: packed,
# little-endian, 29 bytes. The field ranges are AgentCommand's own (speeds int16,
# counters int32), so the dtype itself keeps every value in range.
MAC_ITEM_DTYPE = np.dtype(
    [
        ("seq", "<u8"),  # the holder session's sequence number (shared with its envelopes)
        ("sent_at", "<f8"),  # wall-clock seconds when sealed
        ("flags", "u1"),  # bit 0: speeds set, bit 1: counters set; others must be 0
        ("speeds", "<i2", (2,)),
        ("counters", "<i4", (2,)),
    ]
)
MAC_ITEM_BYTES = MAC_ITEM_DTYPE.itemsize
# The same record for struct: packing or unpacking 20 of these one by one costs less
# than numpy's fixed overhead per call at a swarm's size (tens of robots).
MAC_ITEM_STRUCT = struct.Struct("<QdBhhii")
assert MAC_ITEM_STRUCT.size == MAC_ITEM_BYTES
MAC_ITEM_SPEEDS = 1
MAC_ITEM_COUNTERS = 2


class MacCommandBundle(Message, frozen=True):
    """Several agents' MACed commands in parallel arrays (``world/<world>/cmds``).

    The array form of a CommandBundle of MacCommands, for a process that
    drives many robots under MAC leases (``WorldChannel.on_swarm``): one
    encode on the sender and one decode on the world per tick instead of one
    of each per robot. Item ``i`` is ``agents[i]``'s command: the
    ``MAC_ITEM_BYTES`` bytes at ``i * MAC_ITEM_BYTES`` of ``items`` (a record
    of ``MAC_ITEM_DTYPE``: seq, sent_at, flags, speeds, counters) and its MAC,
    the 32 bytes at ``i * 32`` of ``macs``: BLAKE2b keyed with the agent's
    lease key, personalised ``wart.cmdarr.v1``, over the length-prefixed key
    expression ``agent/<agent>/cmd`` and lease id, then exactly those record
    bytes (common/world/leasemac.py). Each item is checked on its own, as a
    MacCommand on its agent's key would be; a refused item spares the others.
    Only speeds and counters travel here; other commands go as MacCommands.
    The lengths must agree (``len(agents)`` items and MACs), else the world
    refuses the whole bundle.
    """

    agents: Annotated[list[Ident], msgspec.Meta(max_length=MAX_BUNDLED)]
    items: Annotated[bytes, msgspec.Meta(max_length=MAX_BUNDLED * MAC_ITEM_BYTES)]
    macs: Annotated[bytes, msgspec.Meta(max_length=MAX_BUNDLED * 32)]


class WorldFrame(Message, frozen=True):
    """Every moving pose at one tick (``world/<world>/frame``).

    ``poses`` rows are ``WorldSnapshot.rows`` (agents first, then movable
    objects); when ``layout`` differs from the snapshot's, fetch a new one.
    ``agent_state`` is :class:`AgentStates`, packed.
    """

    world: Ident
    tick: NonNegInt
    sim_time: float
    layout: NonNegInt
    poses: PackedArray  # float32 (rows, 3): x mm, y mm, heading rad
    agent_state: PackedArray  # uint8 (agents, 4): AgentStates.pack
    lights: PackedArray  # uint8 (lights,): 1 lit


class WorldLayout(Message, frozen=True):
    """The world's rows changed (``world/<world>/layout``): a robot added, removed, or
    come online or gone. Put once per change; fetch a new snapshot if ``layout`` differs
    from the one held (the same number a frame carries)."""

    world: Ident
    layout: NonNegInt


FINGERS_OPEN, FINGERS_CLOSED, FINGERS_HOLDING = 0, 1, 2


@dataclass(frozen=True)
class AgentStates:
    """What a frame says of each agent besides its pose: one uint8 column each.

    ``leds``: bit k is LED k lit; ``arm``: the gripper's arm position (0..255; 0
    without a gripper); ``fingers``: FINGERS_OPEN, FINGERS_CLOSED or
    FINGERS_HOLDING (closed on an object); ``presence``: the light barrier
    between the fingers, 0..255 (the simulator's reads 0 or 255, a real robot's
    its raw reading).
    """

    leds: np.ndarray
    arm: np.ndarray
    fingers: np.ndarray
    presence: np.ndarray

    def pack(self) -> PackedArray:
        columns = (self.leds, self.arm, self.fingers, self.presence)
        return PackedArray.from_numpy(np.stack(columns, axis=1).astype(np.uint8, copy=False))

    @classmethod
    def unpack(cls, packed: PackedArray, agents: int) -> AgentStates | None:
        """The columns of a frame's ``agent_state``; None unless it has ``agents`` rows of 4."""
        table = packed.to_numpy()
        if table.ndim != 2 or table.shape != (agents, 4):
            return None
        return cls(table[:, 0], table[:, 1], table[:, 2], table[:, 3])


class ShapeInfo(msgspec.Struct, frozen=True, kw_only=True):
    """An outline in its own frame: circle (radius) or polygon (points, mm)."""

    kind: Literal["circle", "polygon"]
    radius: float = 0.0
    points: list[tuple[float, float]] = msgspec.field(default_factory=list)


class ItemInfo(msgspec.Struct, frozen=True, kw_only=True):
    """An obstacle, movable object or zone of a snapshot."""

    id: Ident
    category: Literal["obstacle", "object", "zone"]
    kind: ShortText  # "wall", "box", "ball", "nest", ...
    shape: ShapeInfo
    x: float
    y: float
    heading: float
    colour: ShortText
    mass: float = 0.0
    resistivity: int = 0


class LightInfo(msgspec.Struct, frozen=True, kw_only=True):
    id: Ident
    x: float
    y: float
    intensity: float
    radius: float
    mode: Literal["on", "off", "blink"]
    period: float
    colour: ShortText
    on: bool


class AgentInfo(msgspec.Struct, frozen=True, kw_only=True):
    id: Ident
    type: Ident
    radius: float
    colour: ShortText
    x: float
    y: float
    heading: float
    gripper: bool
    leds: int
    proximity_sensors: list[tuple[float, float, float]]  # x, y, heading in the robot frame
    proximity_max: int
    speed_limit: int
    online: bool = True  # a real robot (Khepera bridge) unplugged or silent is offline
    # A real robot's pose is "tracked" (the arena camera sees it), "odometry" (no camera,
    # or it stopped tracking) or "not seen" (a live camera lost it: kept where it was
    # last seen); "" in a simulated world, where the pose is the simulation's own.
    pose_from: Literal["", "tracked", "odometry", "not seen"] = ""
    # The gripper's tongs that robots and walls collide with (the joints drive's), each
    # x from, x to, y and half width in the robot frame (mm): a recording's collisions
    # count them as the dry run's physics does. Empty where tongs touch objects only.
    tongs: list[tuple[float, float, float, float]] = msgspec.field(default_factory=list)
    # The robot file's components as (name, role): what a controller of it may call
    # (common/controller/robot.py); empty for a type written in Python.
    components: Annotated[list[tuple[PartName, PartName]], msgspec.Meta(max_length=32)] = (
        msgspec.field(default_factory=list)
    )


class FloorLineInfo(msgspec.Struct, frozen=True, kw_only=True):
    """A line painted on the floor (a map's floor layer: what floor sensors read)."""

    points: Annotated[list[tuple[float, float]], msgspec.Meta(max_length=512)]
    width: float
    colour: ShortText


class RobotLook(msgspec.Struct, frozen=True, kw_only=True):
    """How a robot type looks (its robot file's components drawing themselves, mm, robot frame).

    ``segments`` (x0, y0, x1, y1) and the ``roles`` of the components that drew them
    (body, proximity, ambient, sensor): the view draws the selected robot with them.
    """

    type: Ident
    segments: Annotated[list[tuple[float, float, float, float]], msgspec.Meta(max_length=2048)]
    roles: Annotated[list[PartName], msgspec.Meta(max_length=2048)]


MAX_ROBOT_FILE_BYTES = 64 * 1024  # common.robots.robotfile.MAX_BYTES
RobotFileText = Annotated[str, msgspec.Meta(max_length=MAX_ROBOT_FILE_BYTES)]


class WorldSnapshot(Message, frozen=True):
    """The whole world for a late joiner (reply of ``world/<world>/snapshot``)."""

    world: Ident
    tick: NonNegInt
    sim_time: float
    layout: NonNegInt
    tick_s: float
    seed: int
    width: float
    height: float
    items: list[ItemInfo]
    lights: list[LightInfo]
    agents: list[AgentInfo]
    rows: list[Ident]  # WorldFrame.poses row order
    # The world's service-account token (registry-signed, ``world`` permission),
    # when it logged in with one: agent contexts seal lease keys to its box key
    # (common/world/leasemac.py). None: a world without identity, Ed25519 commands only.
    identity: SignedToken | None = None
    # "real": a Khepera bridge (robots on serial ports); nothing can be edited or reset there.
    kind: Literal["sim", "real"] = "sim"
    # The map's floor layer (docs/MAPS.md): its lines, drawn on the floor; none without one.
    floor_lines: Annotated[list[FloorLineInfo], msgspec.Meta(max_length=256)] = msgspec.field(
        default_factory=list
    )
    # Each robot type's look (types from robot files; none for a type written in Python).
    looks: Annotated[list[RobotLook], msgspec.Meta(max_length=64)] = msgspec.field(
        default_factory=list
    )
    # The robot file of each type its robots use that the lab does not ship (a type
    # saved in the builder, a plugin's), by type name: a runner rebuilding this world
    # for a dry run simulates them from these (common/sim2d/map_robots.py).
    robot_files: Annotated[dict[Ident, RobotFileText], msgspec.Meta(max_length=32)] = msgspec.field(
        default_factory=dict
    )


class AgentCommand(Message, frozen=True):
    """Actuator commands to one agent (sealed in an AuthEnvelope on ``agent/<agent>/cmd``).

    Fields left None are unchanged. An empty command only feeds the watchdog.
    The fields carry the controller's names (``common.controller.RobotCommand``)
    and map onto a robot's actuators in one place
    (``common.controller.actuators.apply_command``).
    """

    agent: Ident
    speeds: tuple[Speed, Speed] | None = None  # clamped by the type (Khepera +-127)
    counters: tuple[Counter, Counter] | None = None  # set the position counters
    # LED i on or off; LEDs the robot lacks are ignored (an e-puck has 8, a Khepera 2).
    leds: Annotated[list[bool], msgspec.Meta(max_length=16)] | None = None
    arm: Byte | None = None
    grip: bool | None = None  # True closes the gripper's fingers, False opens them


class Lease(Message, frozen=True):
    """Who may command an agent, and when (sealed, on ``agent/<agent>/lease``).

    Issued by a principal with the ``lease`` permission (the agent context)
    and republished periodically, so a restarted engine learns it. A lease
    with the same id replaces the earlier one (e.g. ended early).
    """

    lease_id: Ident
    world: Ident
    agent: Ident
    holder_user: Ident
    holder_session: SessionId
    start: float  # wall-clock seconds (time.time())
    end: float
    # A MAC lease (common/world/leasemac.py): the lease key K sealed to the holder's
    # session box key and to the world's box key (``world_box`` names which,
    # since a world's session, and so its box key, is renewed). Absent, or the
    # world cannot open its copy: commands are Ed25519 AuthEnvelopes as before.
    holder_key: SealedKey | None = None
    world_key: SealedKey | None = None
    world_box: Bytes32 | None = None
    # The session whose request this lease serves: the student who uploaded a
    # deployed controller (the holder is then the runner), or the holder itself
    # (remote). The world lets it reset the agent while the lease is in force.
    requester_session: SessionId | None = None


class WorldStop(Message, frozen=True):
    """Emergency stop of a whole world (sealed by the agent context, ``lease`` permission).

    ``engaged``: every robot's wheels stop at once, every lease in force is
    dropped and commands are refused until a later ``engaged=False``. The
    context republishes an engaged stop every second (a restarted world
    learns it); a world obeys only stops sealed after it started, newer than
    the last one it obeyed, and each envelope once (replay).
    """

    engaged: bool
    by: Ident  # who pressed it (the context's own name when it republishes)
    reason: ShortText = ""  # "emergency stop by <who>: why", shown in the world's log


class MacCommand(Message, frozen=True):
    """An AgentCommand under a MAC lease (on ``agent/<agent>/cmd``, instead of an AuthEnvelope).

    ``mac`` is BLAKE2b keyed with the lease key over the key expression,
    ``lease_id``, ``seq``, ``sent_at`` and ``body`` (an encoded AgentCommand):
    a few µs to check where an Ed25519 envelope costs 60-150 µs.
    """

    lease_id: Ident
    seq: NonNegInt
    sent_at: float
    body: bytes
    mac: Bytes32


class AddItem(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    """Add an entry, written as in a map file's section (see docs/MAPS.md).

    ``nearest_free`` (agents, round objects): the entry's x, y is where the user asked
    for it (the arena's centre, or a click); the world puts it at the nearest spot
    there where it touches nothing, and refuses only when the arena has none.
    """

    section: Literal["obstacles", "objects", "lights", "zones", "agents"]
    entry: dict[str, Any]
    nearest_free: bool = False


class MoveItem(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    id: Ident
    x: Millimetres
    y: Millimetres
    heading: float | None = None  # radians; None keeps it


class RotateItem(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    id: Ident
    heading: float  # radians


class RemoveItem(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    id: Ident


class ResizeArena(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    width: Positive
    height: Positive


class ResetAgent(msgspec.Struct, frozen=True, tag=True, kw_only=True):
    """Put an agent back at its start pose (the map's, or where a map editor last put it).

    Allowed to a map editor, and to the holder or the requester of the agent's
    lease while it is in force (a student resets the robot their controller drives).
    """

    id: Ident


EditOp = AddItem | MoveItem | RotateItem | RemoveItem | ResizeArena | ResetAgent


class WorldEdit(Message, frozen=True):
    """A live edit (sealed, on ``world/<world>/edit``): ``edit_map``, except ResetAgent."""

    op: EditOp


class EditResult(Message, frozen=True):
    """Reply to a WorldEdit or MapRequest that succeeded."""

    layout: NonNegInt
    detail: ShortText = ""
    maps: list[Ident] = msgspec.field(default_factory=list)


RobotTypeName = Annotated[str, msgspec.Meta(pattern=r"^[a-z][a-z0-9_-]{0,31}$")]


class RobotTypeRequest(Message, frozen=True):
    """The robot types a world knows: list them, get one's file, or save a new one (sealed).

    ``save`` (``edit_map``): ``text`` is a robot file (docs/ROBOTS.md), validated by
    the world against its components and kept in its robot directory; data only,
    never executed. The reply's ``detail`` says what was saved, or the refusal
    names the file's line and field.
    """

    action: Literal["list", "get", "save"]
    name: RobotTypeName | None = None  # get
    text: RobotFileText | None = None  # save


class RobotTypeInfo(msgspec.Struct, frozen=True, kw_only=True):
    name: RobotTypeName
    origin: ShortText  # built-in, a plugin's distribution, or the lab's robot directory
    components: list[tuple[PartName, PartName]]  # (name in the file, component type)


class RobotTypeReply(Message, frozen=True):
    types: list[RobotTypeInfo] = msgspec.field(default_factory=list)  # list
    component_types: list[PartName] = msgspec.field(default_factory=list)  # list
    name: RobotTypeName | None = None  # get, save
    text: str = ""  # get: the robot file
    detail: ShortText = ""  # save: what was saved


class MapRequest(Message, frozen=True):
    """Save the world to a map, load another, or list them (sealed, ``edit_map``)."""

    action: Literal["save", "load", "list"]
    name: Ident | None = None  # a map's name in the engine's maps directory (no path)
