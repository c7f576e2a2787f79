"""What a recording holds: one record type per MCAP channel, each with its JSON schema.

Every channel is JSON (``message_encoding="json"``) with a ``jsonschema``
schema generated from the record type below, so any MCAP tool can read it and
Foxglove plots any numeric field without our code. Three kinds of channel use
Foxglove's well-known schemas so its panels understand them: the robot's pose
(``foxglove.PoseInFrame``, metres and a quaternion, for the 3D panel), the
controller's output (``foxglove.Log``, for the Log panel) and a real arena's
camera (``foxglove.CompressedImage``, JPEG, for the Image panel).

These are file records, not wire messages (nothing here travels over Zenoh):
they are plain msgspec Structs, versioned by :data:`FORMAT_VERSION` in the
run record and the MCAP profile.
"""

from __future__ import annotations

from typing import Any

import msgspec

from common.messages import WorldSnapshot

FORMAT_VERSION = 1
PROFILE = "wart"  # the MCAP header's profile: files we wrote
JSON = "json"
SOURCE_MEDIA_TYPE = "text/x-python"  # the attachment holding a deploy run's controller file

# --- topics (the names a tool shows) ---------------------------------------------------

RUN = "/run/info"
END = "/run/end"
SNAPSHOT = "/world/snapshot"
FRAME = "/world/frame"
OUTPUT = "/controller/output"
EVENTS = "/context/events"
CHAT = "/context/chat"
TRACKED = "/tracking/poses"


def pose_topic(agent: str) -> str:
    return f"/robot/{agent}/pose"


def sensors_topic(agent: str) -> str:
    return f"/robot/{agent}/sensors"


def commands_topic(agent: str) -> str:
    return f"/robot/{agent}/commands"


def tracked_topic(agent: str) -> str:
    """The robot's pose as the arena's camera tracked it (a real run)."""
    return f"/robot/{agent}/tracked"


def camera_topic(camera: str, view: str = "image") -> str:
    """``image``: the frame as the camera saw it; ``floor``: rectified to the arena
    (2 mm a pixel, +y up), what a replay lays under its world view."""
    return f"/camera/{camera}/{view}"


class RunInfo(msgspec.Struct, frozen=True, kw_only=True):
    """Whose run this is (``/run/info``, first message of the file)."""

    format: int = FORMAT_VERSION
    ctx: str
    world: str
    agent: str
    user: str
    request_id: str
    mode: str  # remote | deploy
    filename: str = ""
    start: float  # wall-clock seconds: the slot's start
    planned_end: float  # the slot's end as granted
    # An uploaded (deploy) run's file is attached (SOURCE_MEDIA_TYPE, named ``filename``)
    # so the run can be promoted to the real robot as it was; this is its SHA-256.
    source_sha256: str = ""


class RunEnd(msgspec.Struct, frozen=True, kw_only=True):
    """How the run ended (``/run/end``, last message): the context's final status."""

    status: str  # finished | cancelled | refused
    reason: str
    at: float


class FrameRecord(msgspec.Struct, frozen=True, kw_only=True):
    """Every moving pose at one tick (``/world/frame``): rows as in the snapshot.

    The first ``agents`` rows are robots, then movable objects. ``fingers`` per
    robot: 0 open, 1 closed, 2 holding.
    """

    tick: int
    sim_time: float
    layout: int
    agents: int
    rows: list[str]
    x: list[float]  # mm
    y: list[float]  # mm
    heading: list[float]  # rad
    fingers: list[int]


class SampleRecord(msgspec.Struct, frozen=True, kw_only=True):
    """What the slot's robot sensed at one tick (``/robot/<a>/sensors``)."""

    agent: str
    tick: int
    sim_time: float
    proximity: list[int]
    ambient: list[int]
    counters: tuple[int, int]
    speeds: tuple[int, int]  # measured wheel speeds, the type's units
    leds: list[int]
    gripper: dict[str, Any] | None = None


class CommandRecord(msgspec.Struct, frozen=True, kw_only=True):
    """A command the world obeys (``/robot/<a>/commands``): the lease holder's, in force.

    ``sender`` is the account whose session sealed it (the runner's for an
    upload, the student's for ``wart control``); ``auth`` says how it was
    checked (``mac`` under a MAC lease, else ``signed``).
    """

    agent: str
    sender: str
    auth: str
    speeds: tuple[int, int] | None = None
    counters: tuple[int, int] | None = None
    # The command's own names (AgentCommand's). Recordings made before the command
    # carried the controller's names hold LEDs as 0 off, 1 on, 2 toggle, and the
    # gripper as ``fingers`` "open"/"closed": still read, never written.
    leds: list[bool | int] | None = None
    arm: int | None = None
    grip: bool | None = None
    fingers: str | None = None


class EventRecord(msgspec.Struct, frozen=True, kw_only=True):
    """A context event about the run or its robot (``/context/events``).

    ``kind``: queued, running, finished, cancelled, refused (the request's
    status), ``taken`` / ``handed_back`` (a teacher took the robot over, the
    controller paused; and gave it back: ``reason`` in words), or ``queue``
    (the robot's queue changed: ``detail`` lists it).
    """

    kind: str
    request_id: str = ""
    agent: str = ""
    user: str = ""
    reason: str = ""
    detail: str = ""


class ChatRecord(msgspec.Struct, frozen=True, kw_only=True):
    """A chat line said in the context during the run (``/context/chat``)."""

    seq: int
    sender: str
    text: str


# --- Foxglove's well-known schemas (https://docs.foxglove.dev/docs/visualization/message-schemas)


class Time(msgspec.Struct, frozen=True):
    sec: int
    nsec: int


class Vector3(msgspec.Struct, frozen=True):
    x: float
    y: float
    z: float


class Quaternion(msgspec.Struct, frozen=True):
    x: float
    y: float
    z: float
    w: float


class Pose(msgspec.Struct, frozen=True):
    position: Vector3
    orientation: Quaternion


class PoseInFrame(msgspec.Struct, frozen=True):
    """foxglove.PoseInFrame: the slot's robot (metres: Foxglove's unit)."""

    timestamp: Time
    frame_id: str
    pose: Pose


class TrackedRobotRecord(msgspec.Struct, frozen=True):
    agent: str
    x: float  # mm
    y: float
    heading: float  # rad


class TrackedRecord(msgspec.Struct, frozen=True, kw_only=True):
    """The robots a camera found in one frame (``/tracking/poses``), arena mm; the log
    time is the frame's capture time, so video, poses and telemetry share one clock."""

    camera: str
    robots: list[TrackedRobotRecord]


class CompressedImage(msgspec.Struct, frozen=True):
    """foxglove.CompressedImage: one camera frame (JPEG), at a reduced rate."""

    timestamp: Time
    frame_id: str
    data: bytes  # base64 in JSON, as Foxglove reads it
    format: str


class LogLine(msgspec.Struct, frozen=True):
    """foxglove.Log: one line the controller printed (level 2 info, 4 error)."""

    timestamp: Time
    level: int
    message: str
    name: str
    file: str
    line: int


FOXGLOVE_NAMES: dict[type, str] = {
    PoseInFrame: "foxglove.PoseInFrame",
    LogLine: "foxglove.Log",
    CompressedImage: "foxglove.CompressedImage",
}

RECORD_TYPES: dict[str, type] = {
    RUN: RunInfo,
    END: RunEnd,
    SNAPSHOT: WorldSnapshot,
    FRAME: FrameRecord,
    OUTPUT: LogLine,
    EVENTS: EventRecord,
    CHAT: ChatRecord,
    TRACKED: TrackedRecord,
}
"""Topic -> record type; the per-robot topics are matched by their last chunk."""

ROBOT_TYPES: dict[str, type] = {
    "pose": PoseInFrame,
    "tracked": PoseInFrame,
    "sensors": SampleRecord,
    "commands": CommandRecord,
}


def record_type(topic: str) -> type | None:
    """The record type of a topic, or None for a topic this version does not know."""
    if topic in RECORD_TYPES:
        return RECORD_TYPES[topic]
    parts = topic.split("/")
    if len(parts) == 4 and parts[1] == "robot":
        return ROBOT_TYPES.get(parts[3])
    if len(parts) == 4 and parts[1] == "camera" and parts[3] in ("image", "floor"):
        return CompressedImage
    return None


def schema_name(cls: type) -> str:
    return FOXGLOVE_NAMES.get(cls, f"wart.{cls.__name__}")


def json_schema(cls: type) -> bytes:
    """The JSON schema of a record type (draft 2020-12, what msgspec generates)."""
    schema = msgspec.json.schema(cls)
    if "$ref" in schema:  # inline the top definition: tools expect an object at the root
        name = schema["$ref"].rsplit("/", 1)[-1]
        defs = schema.get("$defs", {})
        top = dict(defs.pop(name))
        if defs:
            top["$defs"] = defs
        schema = top
    schema["title"] = schema_name(cls)
    return msgspec.json.encode(schema)


def stamp(t: float) -> Time:
    sec = int(t)
    return Time(sec, int((t - sec) * 1e9))
