"""A recording as a ROS 2 bag (MCAP storage, ROS 2 message types), for ROS 2 tools.

rosbag2's tools, rviz2 (through ``ros2 bag play``), Foxglove with ROS schemas and
PlotJuggler read the bag; the lab's own recording (JSON channels, common/recording/
schema.py) stays what the lab writes. The messages are encoded by the ``rosbags``
library (the ``ros`` extra, pure Python): its type store of ROS 2 Jazzy, its CDR
serializer and its rosbag2 writer. Topics (``A``: the run's robot):

- ``/tf`` (tf2_msgs/TFMessage): every robot of each world frame, ``arena`` to
  ``<robot>/base_link``;
- ``/A/odom`` (nav_msgs/Odometry): the run's robot's pose, and its velocity from
  one pose to the next, in the robot's frame;
- ``/A/ir/proximity``, ``/A/ir/ambient`` (std_msgs/Float32MultiArray): the IR
  sensors' raw readings, in the robot type's order and units;
- ``/A/joint_states`` (sensor_msgs/JointState): the measured wheel speeds
  (velocity) and counters (position), the robot type's raw units;
- ``/A/cmd_vel`` (geometry_msgs/Twist): each wheel-speed command in force, as the
  body's forward (m/s) and turning (rad/s) speed from the type's drive;
- ``/A/tracked`` (geometry_msgs/PoseStamped): the pose a real arena's camera saw;
- ``/camera/<camera>/<view>/compressed`` (sensor_msgs/CompressedImage): its frames;
- ``/rosout`` (rcl_interfaces/Log): what the controller printed.

Every message is logged at the recording's own time (nanoseconds since the epoch).
"""

from __future__ import annotations

import importlib.util
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np

from common.recording import schema as s
from common.recording.reader import Recording, Stamped
from common.robots import registry
from common.robots.robotfile import DriveSpec

# rosbag2's metadata version: the older of the two rosbags writes (8 added ros_distro;
# 9 changed how QoS profiles are written), for the older ROS 2 tools that read it.
BAG_VERSION: Final = 8
WORLD_FRAME = "arena"
ROS_INSTALL = "pip install 'wart-lab[ros]'"

ODOMETRY = "nav_msgs/msg/Odometry"
TF = "tf2_msgs/msg/TFMessage"
FLOATS = "std_msgs/msg/Float32MultiArray"
JOINTS = "sensor_msgs/msg/JointState"
TWIST = "geometry_msgs/msg/Twist"
POSE = "geometry_msgs/msg/PoseStamped"
IMAGE = "sensor_msgs/msg/CompressedImage"
LOG = "rcl_interfaces/msg/Log"

# foxglove.Log's levels (1 debug .. 5 fatal) as rcl_interfaces/Log's (10 .. 50)
_LOG_LEVELS = {1: 10, 2: 20, 3: 30, 4: 40, 5: 50}


class RosbagsMissing(RuntimeError):
    """The ``rosbags`` library is not installed (the ``ros`` extra)."""


def available() -> bool:
    return importlib.util.find_spec("rosbags") is not None


@dataclass
class Export:
    """What :func:`write_bag` wrote: the bag's directory, messages per topic, and what
    it could not convert (said to the user)."""

    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    types: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _ns(t: float) -> int:
    return round(t * 1e9)


def heading_of(pose: s.PoseInFrame) -> float:
    q = pose.pose.orientation
    return 2.0 * math.atan2(q.z, q.w)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def body_speeds(drive: DriveSpec, left: int, right: int) -> tuple[float, float]:
    """Wheel speeds in the type's units as the body's forward m/s and turning rad/s."""
    scale = drive.mm_per_pulse / drive.unit_time_s / 1000.0
    v_left, v_right = left * scale, right * scale
    return (v_left + v_right) / 2.0, (v_right - v_left) / (drive.wheel_base_mm / 1000.0)


def drive_of(recording: Recording) -> DriveSpec | None:
    """The drive of the run's robot's type: a type the lab ships, or the robot file the
    world carried; None when neither is known here (a plugin's type)."""
    snapshot = recording.snapshot
    if recording.info is None or snapshot is None:
        return None
    kind = next((a.type for a in snapshot.agents if a.id == recording.info.agent), None)
    if kind is None:
        return None
    types = registry.build(plugins=False)
    try:
        if kind in snapshot.robot_files:
            return types.world_type(kind, snapshot.robot_files[kind]).drive
    except ValueError:
        return None
    spec = types.robots.get(kind)
    return spec.drive if spec is not None else None


class _Bag:
    """One bag being written: its connections by topic, and the messages counted."""

    def __init__(self, writer: Any, store: Any, export: Export) -> None:
        self.writer = writer
        self.store = store
        self.export = export
        self.connections: dict[str, Any] = {}

    def write(self, topic: str, msgtype: str, t: float, message: Any) -> None:
        connection = self.connections.get(topic)
        if connection is None:
            connection = self.writer.add_connection(topic, msgtype, typestore=self.store)
            self.connections[topic] = connection
            self.export.types[topic] = msgtype
        data = self.store.serialize_cdr(message, msgtype)
        self.writer.write(connection, _ns(t), data)
        self.export.counts[topic] = self.export.counts.get(topic, 0) + 1


class _Messages:
    """The ROS 2 messages of the type store, built from the lab's records."""

    def __init__(self, store: Any) -> None:
        self.t = store.types

    def time(self, t: float) -> Any:
        sec = math.floor(t)
        return self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9))

    def header(self, t: float, frame: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=self.time(t), frame_id=frame)

    def vector(self, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Any:
        return self.t["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    def quaternion(self, heading: float) -> Any:
        return self.t["geometry_msgs/msg/Quaternion"](
            x=0.0, y=0.0, z=math.sin(heading / 2.0), w=math.cos(heading / 2.0)
        )

    def pose(self, x_m: float, y_m: float, heading: float) -> Any:
        point = self.t["geometry_msgs/msg/Point"](x=x_m, y=y_m, z=0.0)
        return self.t["geometry_msgs/msg/Pose"](
            position=point, orientation=self.quaternion(heading)
        )

    def twist(self, forward: float, turning: float) -> Any:
        return self.t["geometry_msgs/msg/Twist"](
            linear=self.vector(x=forward), angular=self.vector(z=turning)
        )

    def transform(self, t: float, child: str, x_m: float, y_m: float, heading: float) -> Any:
        transform = self.t["geometry_msgs/msg/Transform"](
            translation=self.vector(x_m, y_m), rotation=self.quaternion(heading)
        )
        return self.t["geometry_msgs/msg/TransformStamped"](
            header=self.header(t, WORLD_FRAME), child_frame_id=child, transform=transform
        )

    def floats(self, values: list[int], label: str) -> Any:
        dim = self.t["std_msgs/msg/MultiArrayDimension"](
            label=label, size=len(values), stride=len(values)
        )
        layout = self.t["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)
        return self.t[FLOATS](layout=layout, data=np.asarray(values, dtype=np.float32))


def write_bag(recording: Recording, dest: Path) -> Export:
    """Write ``recording`` as a ROS 2 bag in the new directory ``dest``.

    RosbagsMissing when the ``ros`` extra is not installed; FileExistsError when
    ``dest`` exists (a bag is never overwritten).
    """
    try:
        # optional (the ros extra): only this export needs it
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise RosbagsMissing(f"a ROS 2 bag needs the rosbags library: {ROS_INSTALL}") from None
    if dest.exists():
        raise FileExistsError(f"{dest} exists: a bag is written to a new directory")
    store = get_typestore(Stores.ROS2_JAZZY)
    export = Export(path=dest)
    with Writer(dest, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP) as writer:
        bag = _Bag(writer, store, export)
        for part in _PARTS:
            part(bag, _Messages(store), recording)
    return export


def _transforms(bag: _Bag, m: _Messages, rec: Recording) -> None:
    for stamped in rec.frames:
        frame = stamped.record
        transforms = [
            m.transform(
                stamped.t,
                f"{frame.rows[i]}/base_link",
                frame.x[i] / 1000.0,
                frame.y[i] / 1000.0,
                frame.heading[i],
            )
            for i in range(min(frame.agents, len(frame.x)))
        ]
        bag.write("/tf", TF, stamped.t, m.t[TF](transforms=transforms))


def _odometry(bag: _Bag, m: _Messages, rec: Recording) -> None:
    if rec.info is None:
        return
    agent = rec.info.agent
    before: Stamped[s.PoseInFrame] | None = None
    covariance = [0.0] * 36
    for stamped in rec.poses:
        pose = stamped.record
        x, y, heading = pose.pose.position.x, pose.pose.position.y, heading_of(pose)
        forward = turning = 0.0
        if before is not None and stamped.t > before.t:
            dt = stamped.t - before.t
            p0 = before.record.pose.position
            forward = ((x - p0.x) * math.cos(heading) + (y - p0.y) * math.sin(heading)) / dt
            turning = _wrap(heading - heading_of(before.record)) / dt
        before = stamped
        odometry = m.t[ODOMETRY](
            header=m.header(stamped.t, WORLD_FRAME),
            child_frame_id=f"{agent}/base_link",
            pose=m.t["geometry_msgs/msg/PoseWithCovariance"](
                pose=m.pose(x, y, heading), covariance=_array(covariance)
            ),
            twist=m.t["geometry_msgs/msg/TwistWithCovariance"](
                twist=m.twist(forward, turning), covariance=_array(covariance)
            ),
        )
        bag.write(f"/{agent}/odom", ODOMETRY, stamped.t, odometry)


def _array(values: list[float]) -> Any:
    """rosbags' arrays of numbers are numpy arrays."""
    return np.asarray(values, dtype=np.float64)


def _sensors(bag: _Bag, m: _Messages, rec: Recording) -> None:
    for stamped in rec.samples:
        sample = stamped.record
        a = sample.agent
        bag.write(f"/{a}/ir/proximity", FLOATS, stamped.t, m.floats(sample.proximity, "sensor"))
        bag.write(f"/{a}/ir/ambient", FLOATS, stamped.t, m.floats(sample.ambient, "sensor"))
        joints = m.t[JOINTS](
            header=m.header(stamped.t, f"{a}/base_link"),
            name=["left_wheel", "right_wheel"],
            position=_array([float(c) for c in sample.counters]),
            velocity=_array([float(v) for v in sample.speeds]),
            effort=_array([]),
        )
        bag.write(f"/{a}/joint_states", JOINTS, stamped.t, joints)


def _commands(bag: _Bag, m: _Messages, rec: Recording) -> None:
    speeds = [c for c in rec.commands if c.record.speeds is not None]
    if not speeds:
        return
    drive = drive_of(rec)
    if drive is None:
        bag.export.notes.append(
            f"{len(speeds)} wheel commands not written: the robot's type is not one this "
            "install knows (its drive converts them to cmd_vel)"
        )
        return
    for stamped in speeds:
        command = stamped.record
        assert command.speeds is not None
        forward, turning = body_speeds(drive, *command.speeds)
        bag.write(f"/{command.agent}/cmd_vel", TWIST, stamped.t, m.twist(forward, turning))


def _tracked(bag: _Bag, m: _Messages, rec: Recording) -> None:
    if rec.info is None:
        return
    for stamped in rec.tracked_poses:
        pose = stamped.record
        message = m.t[POSE](
            header=m.header(stamped.t, WORLD_FRAME),
            pose=m.pose(pose.pose.position.x, pose.pose.position.y, heading_of(pose)),
        )
        bag.write(f"/{rec.info.agent}/tracked", POSE, stamped.t, message)


def _images(bag: _Bag, m: _Messages, rec: Recording) -> None:
    for stamped in rec.images:
        image = stamped.record
        topic = f"/{image.frame_id.strip('/')}/compressed"  # frame_id: camera/<name>/<view>
        t = image.timestamp.sec + image.timestamp.nsec / 1e9
        message = m.t[IMAGE](
            header=m.header(t, image.frame_id),
            format=image.format,
            data=np.frombuffer(image.data, dtype=np.uint8),
        )
        bag.write(topic, IMAGE, stamped.t, message)


def _output(bag: _Bag, m: _Messages, rec: Recording) -> None:
    for stamped in rec.output:
        line = stamped.record
        log = m.t[LOG](
            stamp=m.time(stamped.t),
            level=_LOG_LEVELS.get(line.level, 20),
            name=line.name or "controller",
            msg=line.message,
            file=line.file,
            function="",
            line=max(0, line.line),
        )
        bag.write("/rosout", LOG, stamped.t, log)


_PARTS: tuple[Callable[[_Bag, _Messages, Recording], None], ...] = (
    _transforms,
    _odometry,
    _sensors,
    _commands,
    _tracked,
    _images,
    _output,
)
