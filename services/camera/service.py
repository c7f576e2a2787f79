"""``wart camera``: one camera over a world's arena, its frames and the robots it tracks.

One process per camera, supervised like every service. A thread captures from
the source at the configured rate, finds the marked robots (once calibrated)
and publishes, newest only (congestion control: drop), each frame as a JPEG
(``world/<w>/camera/<c>/image``), the arena's floor seen from straight above
when calibrated (``.../floor``: what the page lays under its world view), and
the tracked poses (``world/<w>/tracked``, for the bridge, the page and the
recorder). ``world/<w>/camera/<c>/status`` says whether it sees its arena and,
if not, why: unplugged, the file ended, not calibrated. A video file plays as a
recording (services/camera/sources.py's Recording): its frames stamped with its
own timeline, its end final unless it loops.

The markers' layout comes from the world's own snapshot (its arena's size and
its robots' names: robot kN wears marker N), so nothing is configured twice. The
snapshot is read again when the world says its rows changed
(``world/<w>/layout``: a robot added, plugged in or gone), and every
``layout_check_s`` besides, in case that news was lost: a robot added after the
camera started is tracked from the world's next frame, not half a minute later.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import zenoh

from common import keys
from common.ask import ask
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import (
    CameraFrame,
    CameraStatus,
    TrackedPoses,
    TrackedRobot,
    WorldLayout,
    WorldSnapshot,
    decode,
    encode,
)
from common.messages.camera import MAX_FRAME_BYTES
from common.service import Service, has_subscribers
from common.tracking.calibration import (
    ArenaCalibration,
    CalibrationError,
    calibrate,
    floor_calibrated,
    read_intrinsics,
)
from common.tracking.intrinsics import Intrinsics
from common.tracking.markers import (
    MarkerError,
    MarkerLayout,
    default_layout,
    grid_description,
)
from common.tracking.tracker import Tracker
from common.worker import Worker
from services.camera.arguments import DEFAULT_HEIGHT_MM
from services.camera.sources import FrameSource, SourceEnded, SourceError

STATUS_PERIOD_S = 2.0
RETRY_S = 2.0
LIVE_FPS = 10.0
FLOOR_MM_PER_PX = 2.0  # the floor view's resolution: a 1 m arena is 500 px


@dataclass(frozen=True)
class CameraOptions:
    fps: float | None = None  # None: a live source at LIVE_FPS, a recording at its own
    max_width: int = 640
    max_height: int = 480
    jpeg_quality: int = 70
    calibration: Path | None = None
    auto_calibrate: bool = False
    camera_height_mm: float | None = None  # None: solved with a lens, else 1500 said
    reference_grid: tuple[int, int] = (2, 2)  # the reference markers: the corners
    layout_check_s: float = 30.0  # the world's robots read again without its news


class CameraService(Service):
    kind = AliveKind.CAMERA

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        name: str,
        *,
        world: str,
        source: FrameSource,
        options: CameraOptions | None = None,
    ) -> None:
        super().__init__(session, realm, name)
        keys.check_ident("world", world)
        self.world = world
        self.source = source
        self.options = options or CameraOptions()
        self.calibration: ArenaCalibration | None = None
        self.lens: Intrinsics | None = None
        self.layout: MarkerLayout | None = None
        self.tracker: Tracker | None = None
        self.online = False
        self.reason = "starting"
        self.frames = 0
        self.size = (0, 0)
        self._fps = 0.0
        self._worker = Worker(self._run, f"camera-{self.ident}")
        self._told: set[str] = set()
        self._status_at = 0.0
        self._next_layout = 0.0
        self._next_calibration = 0.0
        self._arena: tuple[float, float] | None = None
        self._shown: tuple[bool, bool] = (False, False)

    # -- lifecycle

    def on_start(self) -> None:
        path = self.options.calibration
        if path is not None and path.exists():
            # A file with the lens only: the floor is calibrated here (main checked that
            # --auto-calibrate is on), with that lens. Errors: main said them already.
            self.lens = read_intrinsics(path)
            if floor_calibrated(path):
                self.calibration = ArenaCalibration.load(path)
            elif self.lens is not None:
                self.log.info("lens from %s: %s", path, self.lens.summary())
        if self.calibration is not None and path is not None:
            self.log.info(
                "calibration %s: made at %dx%d; %s",
                path,
                *self.calibration.image_size,
                self.calibration.report(),
            )
            for warning in self.calibration.warnings():
                self.log.warning("%s", warning)
        drop = zenoh.CongestionControl.DROP
        self._image_pub = self.track(
            self.session.declare_publisher(
                keys.camera_frame(self.realm, self.world, self.ident), congestion_control=drop
            )
        )
        self._floor_pub = self.track(
            self.session.declare_publisher(
                keys.camera_floor(self.realm, self.world, self.ident), congestion_control=drop
            )
        )
        self.subscribe(keys.world_layout(self.realm, self.world), self.on_world_layout)
        self._tracked_pub = self.track(
            self.session.declare_publisher(
                keys.world_tracked(self.realm, self.world), congestion_control=drop, express=True
            )
        )
        self._status_pub = self.track(
            self.session.declare_publisher(keys.camera_status(self.realm, self.world, self.ident))
        )
        self._worker.start()

    def on_stop(self, timeout: float) -> None:
        self._worker.stop(timeout)  # the loop ends on the service's stop (self.stopped)
        self.source.close()

    # -- the capture loop

    def _run(self) -> None:
        period = 1.0 / (self.options.fps or LIVE_FPS)
        opened = False
        started, count = time.monotonic(), 0
        next_at = time.monotonic()
        loops = 0
        while not self.stopped:
            now = time.monotonic()
            if now >= self._next_layout:
                self._refresh_layout()
            try:
                if not opened:
                    self.source.open()
                    opened = True
                    self._say_once("open", f"capturing from the {self.source.description}")
                frame = self.source.read()
            except SourceEnded as exc:
                # A recording that ended stays ended: offline until the camera is stopped.
                self.source.close()
                self._set_offline(str(exc))
                while not self._stopped.wait(STATUS_PERIOD_S):
                    self._publish_status()
                return
            except SourceError as exc:
                if opened:
                    self.source.close()
                opened = False
                self._set_offline(str(exc))
                self._stopped.wait(RETRY_S)
                continue
            for note in self.source.notes():
                self.log.warning("%s", note)
            if self.source.loops != loops:
                loops = self.source.loops
                self._say_once(
                    "loop",
                    f"the {self.source.description} ended: playing it again from its start "
                    "(--loop); its timeline carries on and each robot is tracked afresh, "
                    "never as a jump",
                )
                self._make_tracker()
            captured_at = self.source.captured_at or time.time()
            self._publish(frame, captured_at)
            count += 1
            if time.monotonic() - started >= 2.0:
                self._fps = count / (time.monotonic() - started)
                started, count = time.monotonic(), 0
            if self.source.paces_itself:  # a recording: its own rate (or --fps samples it)
                continue
            next_at = max(next_at + period, time.monotonic() - period)
            self._stopped.wait(max(0.0, next_at - time.monotonic()))

    def _publish(self, frame: np.ndarray, captured_at: float) -> None:
        self.frames += 1
        height, width = frame.shape[:2]
        self.size = (width, height)
        if not self.online:
            self.online, self.reason = True, ""
            self.log.info(
                "camera online: %dx%d from the %s", width, height, self.source.description
            )
            self._publish_status(force=True)
        self._maybe_calibrate(frame)
        if self.tracker is not None:
            found = self.tracker.track(frame, captured_at)
            robots = [
                TrackedRobot(agent=p.agent, x=p.x, y=p.y, heading=p.heading, marker=p.marker)
                for p in found.poses
            ]
            self._tracked_pub.put(
                encode(
                    TrackedPoses(
                        world=self.world,
                        camera=self.ident,
                        seq=self.frames,
                        captured_at=captured_at,
                        robots=robots,
                        sent_at=time.time(),
                    )
                ),
            )
            # The videos are encoded only while someone watches them (a page, a slot's
            # recording): tracking needs none of it (docs/BENCHMARKS.md, the camera).
            floor = self._floor_view(frame) if has_subscribers(self._floor_pub) else None
            if floor is not None:
                self._put_frame(self._floor_pub, floor, captured_at)
        if has_subscribers(self._image_pub):
            shown = _fit(frame, self.options.max_width, self.options.max_height)
            self._put_frame(self._image_pub, shown, captured_at)
        self._publish_status()

    def _put_frame(self, publisher: zenoh.Publisher, image: np.ndarray, captured_at: float) -> None:
        quality = self.options.jpeg_quality
        while True:
            ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
            if not ok:
                self._say_once("jpeg", "a frame could not be encoded as JPEG: skipped")
                return
            if len(jpeg) <= MAX_FRAME_BYTES or quality <= 20:
                break
            quality -= 20
        if len(jpeg) > MAX_FRAME_BYTES:
            self._say_once(
                "big",
                f"frames are over {MAX_FRAME_BYTES} bytes even at quality 20: lower --max-width",
            )
            return
        height, width = image.shape[:2]
        publisher.put(
            encode(
                CameraFrame(
                    world=self.world,
                    camera=self.ident,
                    seq=self.frames,
                    captured_at=captured_at,
                    width=width,
                    height=height,
                    data=jpeg.tobytes(),
                )
            )
        )

    def _floor_view(self, frame: np.ndarray) -> np.ndarray | None:
        """The arena seen from straight above: image px -> arena mm at FLOOR_MM_PER_PX,
        the arena's +y up (so the page lays it on its floor as it is)."""
        if self.calibration is None or self.layout is None or self._arena is None:
            return None
        w_mm, h_mm = self._arena
        s = 1.0 / FLOOR_MM_PER_PX
        arena_to_floor = np.array([[s, 0.0, 0.0], [0.0, -s, h_mm * s], [0.0, 0.0, 1.0]])
        size = (max(16, int(w_mm * s)), max(16, int(h_mm * s)))
        ideal = self.calibration.undistort_frame(frame)
        return cv2.warpPerspective(ideal, arena_to_floor @ self.calibration.homography, size)

    # -- layout and calibration

    def on_world_layout(self, sample: zenoh.Sample) -> None:
        """The world's rows changed: read its snapshot again at the next frame."""
        news = decode(sample.payload, WorldLayout)  # unreadable: logged by subscribe
        if news.world == self.world:
            self._next_layout = 0.0

    def _refresh_layout(self) -> None:
        """The arena's size and robots from the world's snapshot (asked again now and then:
        robots may be added to a real world's serial ports)."""
        # The next check is set before asking: news of a change that comes while the
        # snapshot is on its way (on_world_layout) makes it due again, not overwritten.
        self._next_layout = time.monotonic() + self.options.layout_check_s
        snapshot = self._snapshot()
        if snapshot is None:
            self._next_layout = min(self._next_layout, time.monotonic() + RETRY_S)
            if self.layout is None:
                self._say_once("no-world", f"waiting for world {self.world} to answer its snapshot")
            return
        agents = [a.id for a in snapshot.agents]
        arena = (float(snapshot.width), float(snapshot.height))
        if (
            self.layout is not None
            and arena == self._arena
            and sorted(self.layout.robots) == sorted(agents)
        ):
            return
        try:
            layout = default_layout(arena[0], arena[1], agents, grid=self.options.reference_grid)
        except MarkerError as exc:  # more robots than ids, or an arena too small for markers
            self._say_once("layout", f"world {self.world}: no marker layout: {exc}")
            return
        self._arena, self.layout = arena, layout
        self.log.info(
            "world %s: arena %.0f x %.0f mm, markers %s; reference markers %s",
            self.world,
            arena[0],
            arena[1],
            ", ".join(f"{a}={i}" for a, i in sorted(self.layout.robots.items())) or "none",
            grid_description(self.layout.reference),
        )
        self._make_tracker()

    def _snapshot(self) -> WorldSnapshot | None:
        return world_snapshot(self.session, self.realm, self.world)

    def _make_tracker(self) -> None:
        if self.layout is None or self.calibration is None:
            self.tracker = None
            return
        if self.size != (0, 0) and self.size != self.calibration.image_size:
            self._say_once(
                "size",
                "the calibration was made at {}x{} but the camera gives {}x{}: no tracking "
                "until it is calibrated again (`wart camera calibrate`)".format(
                    *self.calibration.image_size, *self.size
                ),
            )
            self.tracker = None
            return
        self.tracker = Tracker(self.layout, self.calibration, say=self.log.warning)

    def _maybe_calibrate(self, frame: np.ndarray) -> None:
        if self.tracker is not None or self.layout is None:
            return
        if self.calibration is not None:
            self._make_tracker()
            return
        if not self.options.auto_calibrate:
            self._say_once(
                "uncalibrated",
                "not calibrated: video only, no tracking "
                "(`wart camera calibrate`, or --auto-calibrate)",
            )
            return
        if time.monotonic() < self._next_calibration:
            return
        self._next_calibration = time.monotonic() + 5.0
        lens = self.lens
        if lens is not None and lens.image_size != self.size:
            self._say_once(
                "lens-size",
                "the lens was calibrated at {}x{} but the camera gives {}x{}: calibrating "
                "without it".format(*lens.image_size, *self.size),
            )
            lens = None
        try:
            cal = calibrate(
                frame,
                self.layout,
                camera_height_mm=self._height(lens),
                camera_matrix=lens.camera_matrix if lens else self.source.camera_matrix,
                dist_coeffs=lens.dist_coeffs if lens else self.source.dist_coeffs,
                lens=lens,
            )
        except CalibrationError as exc:
            self._say_once("calibrate", f"cannot calibrate yet: {exc}")
            return
        self.calibration = cal
        where = ""
        if self.options.calibration is not None:
            cal.save(self.options.calibration)
            where = f", saved to {self.options.calibration}"
        self.log.info("calibrated from the reference markers%s: %s", where, cal.report())
        for warning in cal.warnings():
            self.log.warning("%s", warning)
        self._make_tracker()

    def _height(self, lens: Intrinsics | None) -> float | None:
        """The height to calibrate with: the one given, else none with a lens (solved),
        else the default, said once."""
        given = self.options.camera_height_mm
        if given is not None or lens is not None or self.source.camera_matrix is not None:
            return given
        self._say_once(
            "height",
            f"--camera-height not given: {DEFAULT_HEIGHT_MM:g} mm assumed (without the lens's "
            "intrinsics the height is needed; measure it)",
        )
        return DEFAULT_HEIGHT_MM

    # -- status

    def _set_offline(self, reason: str) -> None:
        if self.online or reason != self.reason:
            self.log.warning("camera offline: %s", reason)
        self.online, self.reason = False, reason
        self._publish_status(force=True)

    def _publish_status(self, force: bool = False) -> None:
        """On a change of what the page shows (online, tracking), and every 2 s."""
        now = time.monotonic()
        shown = (self.online, self.tracker is not None)
        if not force and shown == self._shown and now - self._status_at < STATUS_PERIOD_S:
            return
        self._status_at, self._shown = now, shown
        self._status_pub.put(encode(self.status()))

    def status(self) -> CameraStatus:
        return CameraStatus(
            world=self.world,
            camera=self.ident,
            online=self.online,
            reason=self.reason[:256],
            source=self.source.description[:256],
            fps=round(self._fps, 2),
            width=self.size[0],
            height=self.size[1],
            tracking=self.tracker is not None,
            at=time.time(),
        )

    def _say_once(self, what: str, text: str) -> None:
        if what not in self._told:
            self._told.add(what)
            self.log.info("%s", text)


def world_snapshot(session: zenoh.Session, realm: str, world: str) -> WorldSnapshot | None:
    """The world's snapshot, or None when it does not answer within 2 s."""
    try:
        return ask(
            session,
            keys.world_snapshot(realm, world),
            None,
            WorldSnapshot,
            what=f"world {world}",
            timeout=2.0,
        )
    except LabError:
        return None


def _fit(frame: np.ndarray, max_width: int, max_height: int) -> np.ndarray:
    height, width = frame.shape[:2]
    scale = min(max_width / width, max_height / height, 1.0)
    if scale >= 1.0:
        return frame
    return cv2.resize(
        frame, (int(width * scale), int(height * scale)), interpolation=cv2.INTER_AREA
    )
