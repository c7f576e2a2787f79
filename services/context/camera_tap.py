"""A real arena's camera in the recordings: its frames at a reduced rate, every tracked pose.

The recorder subscribes to the world's cameras and tracked poses beside its
frames; this module holds that part. Frames are kept at most
:data:`IMAGE_HZ` a second per camera (a minute is about 5 MB) as Foxglove's
``CompressedImage``: the floor view rectified to the arena when the camera is
calibrated (what a replay lays under its world view), else the frame as seen;
every tracked pose goes in, stamped with the frame's capture time, so the
video, the tracked poses and the robot's own telemetry replay on one clock. A
simulated world has no camera: nothing is subscribed to there that ever speaks.

The cameras' videos are subscribed to only while a slot is recorded: a camera
encodes its videos only while someone watches (services/camera/service.py).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import zenoh

from common import keys
from common.images import ImageRefused, check_image
from common.messages import CameraFrame, MessageError, TrackedPoses, decode
from common.recording import schema as s
from common.recording.writer import pose_record

if TYPE_CHECKING:
    from services.context.recorder import SlotRecorder

IMAGE_HZ = 2.0


class CameraTap:
    def __init__(self, recorder: SlotRecorder) -> None:
        self.recorder = recorder
        self._last_image: dict[str, float] = {}  # key -> when the last kept frame came
        self._floor_at: dict[str, float] = {}  # camera key -> its last floor view

    def subscriptions(self) -> list[tuple[str, Callable[[zenoh.Sample], None]]]:
        """What the recorder subscribes to for its whole life."""
        return [(keys.world_tracked(self.recorder.realm, self.recorder.world), self._on_tracked)]

    def while_recording(self) -> list[tuple[str, Callable[[zenoh.Sample], None]]]:
        """What it subscribes to only while a slot is recorded: the cameras' videos."""
        return [(keys.camera_all(self.recorder.realm, self.recorder.world), self._on_camera)]

    def handlers(self) -> dict[str, Callable[..., None]]:
        return {"camera": self._image, "tracked": self._tracked}

    # -- Zenoh callbacks: a look and a queue put

    def _on_camera(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        view = key.rsplit("/", 1)[-1]
        if view not in ("image", "floor") or not self.recorder.any_recorded():
            return
        camera = key.rsplit("/", 1)[0]
        now = time.monotonic()
        if view == "floor":
            self._floor_at[camera] = now
        elif now - self._floor_at.get(camera, -1e9) < 3.0:
            return  # the floor view is recorded instead
        if now - self._last_image.get(key, 0.0) < 1.0 / IMAGE_HZ:
            return
        self._last_image[key] = now
        self.recorder._put(("camera", sample.payload.to_bytes(), view))

    def _on_tracked(self, sample: zenoh.Sample) -> None:
        if self.recorder.any_recorded():
            self.recorder._put(("tracked", sample.payload.to_bytes()))

    # -- the writer thread

    def _runs(self) -> list[Any]:
        return list(self.recorder._runs.values())

    def _image(self, payload: bytes, view: str = "image") -> None:
        try:  # a replay decodes what is kept here: only an image of the size it says
            frame = decode(payload, CameraFrame)
            check_image(frame.data, claimed=(frame.width, frame.height))
        except (MessageError, ImageRefused):
            return
        topic = s.camera_topic(frame.camera, view)
        record = s.CompressedImage(
            timestamp=s.stamp(frame.captured_at),
            frame_id=topic.strip("/"),
            data=frame.data,
            format=frame.encoding,
        )
        for rec in self._runs():
            rec.writer.write(topic, record, frame.captured_at)

    def _tracked(self, payload: bytes) -> None:
        try:
            poses = decode(payload, TrackedPoses)
        except MessageError:
            return
        record = s.TrackedRecord(
            camera=poses.camera,
            robots=[s.TrackedRobotRecord(r.agent, r.x, r.y, r.heading) for r in poses.robots],
        )
        t = poses.captured_at
        for rec in self._runs():
            rec.writer.write(s.TRACKED, record, t)
            for robot in poses.robots:
                if robot.agent == rec.run.job.agent:
                    pose = pose_record(robot.x, robot.y, robot.heading, t)
                    rec.writer.write(s.tracked_topic(robot.agent), pose, t)
