"""A real arena's camera in the page: its video as the floor of the world view.

The camera publishes its frames rectified to the arena (``world/<w>/camera/<c>/
floor``: 2 mm a pixel, the arena's +y up), so laid on the floor at the arena's
size they line up with the robots drawn at their tracked poses, and no browser
has to know the camera's geometry. One :class:`CameraFeed` per watched world
keeps the newest frame (decoded once, however many browsers watch) and the
camera's status; each browser's :class:`ArenaVideo` draws each new frame on
the pump's next tick (25 a second: a frame waits 20 ms on average, not the
100 ms of the 5 Hz slow tick) and says "camera offline: why" in a notice that
stays until the camera is back.
"""

from __future__ import annotations

import bisect
import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np
import viser
import zenoh

from common import keys
from common.images import ImageRefused, check_image
from common.messages import CameraFrame, CameraStatus, MessageError, decode
from viewers.web import geometry as geo
from viewers.web.world_view import WorldView

VIDEO_NODE = "/world/video"
SILENT_S = 6.0  # a camera says its status every 2 s


class CameraFeed:
    """A real world's cameras, as the viewer watches them (shared by its browsers)."""

    def __init__(self, session: zenoh.Session, realm: str, world: str) -> None:
        self._lock = threading.Lock()
        self._raw: bytes | None = None
        self._count = 0
        self._decoded: tuple[int, np.ndarray, float] | None = None
        self.status: CameraStatus | None = None
        self.heard_at: float | None = None  # the last message of any kind (wall clock)
        self.frames = 0
        self.refused = 0  # frames not decoded: not a PNG or JPEG of the size they say
        self._refused_at = -1
        self._sub = session.declare_subscriber(keys.camera_all(realm, world), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        self.heard_at = time.time()
        key = str(sample.key_expr)
        if key.endswith("/floor"):
            self._raw = sample.payload.to_bytes()  # the newest only: decoded on demand
            self._count += 1
        elif key.endswith("/status"):
            try:
                status = decode(sample.payload.to_bytes(), CameraStatus)
            except MessageError:
                return
            self.status = status

    def floor(self) -> tuple[int, np.ndarray, float] | None:
        """(frame number, RGB image, capture time) of the newest floor view, decoded once."""
        with self._lock:
            count, raw = self._count, self._raw
            if raw is None:
                return None
            if self._decoded is not None and self._decoded[0] == count:
                return self._decoded
            if count == self._refused_at:
                return self._decoded
            try:
                frame = decode(raw, CameraFrame)
                check_image(frame.data, claimed=(frame.width, frame.height))
            except (MessageError, ImageRefused):  # never decoded: the last frame stays
                self._refused_at = count
                self.refused += 1
                return self._decoded
            image = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_COLOR)
            if image is None:  # a frame that fails to decode: keep showing the last
                return self._decoded
            # viser lays an image's first row at the plane's -y edge; the floor view's
            # first row is the arena's far (+y) side, so it goes in upside down.
            rgb = np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)[::-1])
            self._decoded = (count, rgb, frame.captured_at)
            self.frames += 1
            return self._decoded

    def close(self) -> None:
        with contextlib.suppress(zenoh.ZError):  # the session closing first
            self._sub.undeclare()


class ArenaVideo:
    """One browser's view of a real arena's camera (a hook of its world view)."""

    def __init__(self, view: WorldView) -> None:
        self.view = view
        self.shown = -1  # the frame number drawn
        self.said = ""
        self._image: viser.ImageHandle | None = None
        self._notice: viser.NotificationHandle | None = None
        self.delays: deque[float] = deque(maxlen=1000)  # capture to sent, seconds (bench)
        view.tick_hooks.append(self.tick)

    @property
    def image(self) -> viser.ImageHandle | None:
        """The video's scene node (made once per arena shown)."""
        return self._image

    def _camera(self) -> CameraFeed | RecordedCamera | None:
        feed: Any = self.view.feed
        camera = getattr(feed, "camera", None)
        return camera() if callable(camera) else None

    def tick(self) -> None:
        camera = self._camera()
        snap = self.view.snapshot
        if camera is None or snap is None or not snap.real:
            self._clear()
            return
        scene = self.view.client.scene
        floor = camera.floor()
        if floor is not None and floor[0] != self.shown:
            if self._image is None:
                self._image = scene.add_image(
                    VIDEO_NODE,
                    floor[1],
                    render_width=snap.width * geo.MM,
                    render_height=snap.height * geo.MM,
                    format="jpeg",
                    jpeg_quality=80,
                    cast_shadow=False,
                    receive_shadow=False,
                    position=(snap.width * geo.MM / 2, snap.height * geo.MM / 2, -0.0005),
                )
            else:
                # Only the picture changes: a node made again each frame lost its position
                # when the pump batched its messages (seen at 25 Hz in a fresh lab).
                self._image.image = floor[1]
            # Said drawn once it is: a reader of ``shown`` finds the node (JPEG-encoding the
            # first frame took long enough on a busy machine for a test to see neither).
            self.shown = floor[0]
            self.delays.append(time.time() - floor[2])
        status, heard = camera.status, camera.heard_at
        text = ""
        if heard is None:
            text = "no camera over this arena: poses from odometry"
        elif time.time() - heard > SILENT_S:  # it speaks at least every 2 s: gone
            text = "camera offline: it has stopped answering (poses from odometry)"
        elif status is None:
            text = ""  # frames, and its status within 2 s
        elif not status.online:
            text = f"camera offline: {status.reason}"
        elif not status.tracking:
            text = "camera not calibrated: video only, poses from odometry"
        if text != self.said:
            self.said = text
            if self._notice is not None:
                self._notice.remove()
                self._notice = None
            if text:  # held until the camera is back (not a passing toast)
                self._notice = self.view.client.add_notification(
                    f"Camera over {snap.world}", text, with_close_button=True, color="yellow"
                )

    def _clear(self) -> None:
        for handle in (self._image, self._notice):
            if handle is not None:
                handle.remove()
        self._image = self._notice = None
        self.shown, self.said = -1, ""


class RecordedCamera:
    """A real run's recorded floor view at a replay's cursor (the camera of a recording).

    ``images`` are the recording's floor frames with their capture times, in order;
    ``cursor`` gives the replay's time on the same (wall) clock.
    """

    status: CameraStatus | None = None  # a recording has no live camera to be offline

    def __init__(self, images: list[tuple[float, bytes]], cursor: Callable[[], float]) -> None:
        self._times = [t for t, _ in images]
        self._jpegs = [data for _, data in images]
        self._cursor = cursor
        self._decoded: tuple[int, np.ndarray, float] | None = None
        self.frames = 0

    @property
    def heard_at(self) -> float:
        return time.time()

    def floor(self) -> tuple[int, np.ndarray, float] | None:
        i = bisect.bisect_right(self._times, self._cursor()) - 1
        if i < 0:
            return None
        if self._decoded is None or self._decoded[0] != i:
            try:  # a recording is a file from anywhere: its frames are checked too
                check_image(self._jpegs[i])
            except ImageRefused:
                return self._decoded
            image = cv2.imdecode(np.frombuffer(self._jpegs[i], np.uint8), cv2.IMREAD_COLOR)
            if image is None:
                return self._decoded
            rgb = np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2RGB)[::-1])
            self._decoded = (i, rgb, self._times[i])
            self.frames += 1
        return self._decoded
