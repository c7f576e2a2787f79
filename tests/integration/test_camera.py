"""``wart camera`` on a real router beside a real engine: frames, tracked poses, and what a
user is told when the camera goes away or is set up wrong."""

from __future__ import annotations

import math
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from common import keys
from common.ask import ask
from common.auth import RegistryIdentity, issue_session
from common.keys import AliveKind
from common.messages import (
    AddItem,
    CameraFrame,
    CameraStatus,
    EditResult,
    TrackedPoses,
    WorldEdit,
    decode,
)
from common.tracking.calibration import save_intrinsics
from common.tracking.intrinsics import BoardSpec, IntrinsicsCollector
from common.tracking.markers import default_layout
from common.tracking.truth import now_truth, write_truth
from services.lab.supervisor import AliveWatch
from tests.conftest import REPO, Proc, Procs, Router, wait_for
from tests.kit.overhead_camera import BoardCamera, Lens, Mount, OverheadCamera, Robot
from tests.kit.videos import write_video
from tests.kit.waits import Latest

# One worker starts the module's router once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]
WORLD = "w1"
CAMERA = "w1-cam"


class Truth:
    """The emulator's side of the synthetic camera: true poses, written 20 times a second."""

    def __init__(self, path: Path, robots: dict[str, tuple[float, float, float]]) -> None:
        self.path, self.robots = path, robots
        self.paused = threading.Event()
        self._stop = threading.Event()
        write_truth(path, now_truth(1000.0, 1000.0, robots))
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            if not self.paused.is_set():
                write_truth(self.path, now_truth(1000.0, 1000.0, self.robots))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)


def empty_map(tmp_path: Path) -> str:
    """A copy of maps/empty.json (k1, 1 m square) for an engine: it journals its live edits
    beside its map, in the test's directory and not the checkout's."""
    (tmp_path / "maps").mkdir(exist_ok=True)
    return str(shutil.copy(REPO / "maps" / "empty.json", tmp_path / "maps"))


@pytest.fixture
def engine(router: Router, procs: Procs, alive_watch: AliveWatch, tmp_path: Path) -> str:
    """A world to take the camera's marker layout from: maps/empty.json (k1, 1 m square)."""
    proc = procs.start(
        "engine", ["engine", "--map", empty_map(tmp_path), "--world", WORLD, *router.net_args()]
    )
    key = keys.alive(router.realm, AliveKind.WORLD, WORLD)
    assert alive_watch.wait(key, 60.0), proc.output()
    return WORLD


@pytest.fixture
def truth(tmp_path: Path) -> Iterator[Truth]:
    t = Truth(tmp_path / "truth.json", {"k1": (300.0, 650.0, 0.7)})
    yield t
    t.close()


def start_camera(procs: Procs, router: Router, *extra: str) -> Proc:
    return procs.start("camera", ["camera", "--world", WORLD, *extra, *router.net_args()])


def camera_up(procs: Procs, router: Router, alive_watch: AliveWatch, *extra: str) -> Proc:
    """The camera started with ``extra``, once its liveliness token is up."""
    proc = start_camera(procs, router, *extra)
    assert alive_watch.wait(keys.alive(router.realm, AliveKind.CAMERA, CAMERA), 60.0), proc.output()
    return proc


def camera_status(zsession: zenoh.Session, router: Router) -> Latest:
    return Latest(zsession, keys.camera_status(router.realm, WORLD, CAMERA), CameraStatus)


def wait_until_the_file_ended(status: Latest, proc: Proc, reason: str) -> None:
    """Until the camera's status is offline with ``reason`` in its words."""

    def ended() -> bool:
        s = status.get()
        return isinstance(s, CameraStatus) and not s.online and reason in s.reason

    wait_for(ended, 30.0, f"the camera to say its file ended:\n{proc.output()}")


def test_the_camera_tracks_the_robot_and_publishes_its_video(
    router: Router,
    procs: Procs,
    engine: str,
    truth: Truth,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    realm = router.realm
    tracked = Latest(zsession, keys.world_tracked(realm, WORLD), TrackedPoses)
    image = Latest(zsession, keys.camera_frame(realm, WORLD, CAMERA), CameraFrame)
    floor = Latest(zsession, keys.camera_floor(realm, WORLD, CAMERA), CameraFrame)
    status = camera_status(zsession, router)
    cal = tmp_path / "arena.json"
    proc = camera_up(
        procs,
        router,
        alive_watch,
        "--source",
        f"synthetic:{truth.path}",
        "--auto-calibrate",
        "--calibration",
        str(cal),
    )

    def robot_at(x: float, y: float, heading: float) -> bool:
        poses = tracked.get()
        if not isinstance(poses, TrackedPoses) or [r.agent for r in poses.robots] != ["k1"]:
            return False
        r = poses.robots[0]
        return math.hypot(r.x - x, r.y - y) < 3.0 and abs(r.heading - heading) < math.radians(1.5)

    wait_for(
        lambda: robot_at(300.0, 650.0, 0.7), 60.0, f"k1 tracked at its true pose:\n{proc.output()}"
    )
    truth.robots["k1"] = (720.0, 240.0, -2.0)  # the robot drives: the camera follows
    wait_for(lambda: robot_at(720.0, 240.0, -2.0), 20.0, "k1 tracked at its new pose")
    assert cal.exists(), "the calibration made from the reference markers is saved"

    frame = image.get()
    assert isinstance(frame, CameraFrame) and (frame.width, frame.height) == (640, 480)
    picture = cv2.imdecode(np.frombuffer(frame.data, np.uint8), cv2.IMREAD_COLOR)
    assert picture.shape == (480, 640, 3)
    top = wait_for(floor.get, 10.0, "the rectified floor view")
    assert isinstance(top, CameraFrame) and (top.width, top.height) == (500, 500)

    def tracking() -> bool:
        s = status.get()
        return isinstance(s, CameraStatus) and s.online and s.tracking

    wait_for(tracking, 10.0, "the camera's status to say it tracks")
    seen = status.get()
    assert isinstance(seen, CameraStatus) and "synthetic camera" in seen.source


def test_a_camera_that_loses_its_picture_says_so_and_comes_back(
    router: Router,
    procs: Procs,
    engine: str,
    truth: Truth,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
) -> None:
    status = camera_status(zsession, router)
    proc = camera_up(procs, router, alive_watch, "--source", f"synthetic:{truth.path}")

    def online(state: bool) -> bool:
        s = status.get()
        return isinstance(s, CameraStatus) and s.online is state

    wait_for(lambda: online(True), 30.0, "the camera online")
    truth.paused.set()  # the emulator died: its truth goes stale
    wait_for(lambda: online(False), 15.0, "the camera offline")
    s = status.get()
    assert isinstance(s, CameraStatus) and "stopped writing" in s.reason
    assert "camera offline: the emulator stopped writing" in proc.output()
    truth.paused.clear()
    wait_for(lambda: online(True), 15.0, "the camera online again")
    assert proc.popen.poll() is None, "the camera kept running through it"


def test_a_video_file_that_ends_leaves_the_camera_offline_not_dead(
    router: Router,
    procs: Procs,
    engine: str,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    video = write_video(tmp_path / "arena.avi", 10, 20.0, size=(320, 240))
    status = camera_status(zsession, router)
    proc = camera_up(procs, router, alive_watch, "--source", str(video))
    wait_until_the_file_ended(status, proc, "ended")
    assert "not calibrated: video only" in proc.output()
    assert proc.popen.poll() is None


def test_a_recording_says_its_corrupt_frames_and_stays_offline_at_its_end(
    router: Router,
    procs: Procs,
    engine: str,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    video = write_video(tmp_path / "arena.avi", 40, 20.0, corrupt=range(12, 15))
    status = camera_status(zsession, router)
    proc = camera_up(procs, router, alive_watch, "--source", str(video))
    wait_until_the_file_ended(status, proc, "ended after 40 frames")
    said = proc.output()
    assert f"frames 12 to 14 of the video file {video} are corrupt (do not decode)" in said
    assert "give --loop to play it again" in said
    heard = status.count
    wait_for(lambda: status.count >= heard + 2, 15.0, "two more statuses")
    still = status.get()
    assert isinstance(still, CameraStatus) and not still.online, "it stays offline"
    assert proc.output().count("camera online") == 1, proc.output()


def test_a_looping_recording_says_so_and_carries_its_timeline_on(
    router: Router,
    procs: Procs,
    engine: str,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    video = write_video(tmp_path / "arena.avi", 10, 20.0)
    frames = Latest(zsession, keys.camera_frame(router.realm, WORLD, CAMERA), CameraFrame)
    stamps: list[float] = []
    sub = zsession.declare_subscriber(
        keys.camera_frame(router.realm, WORLD, CAMERA),
        lambda sample: stamps.append(decode(sample.payload, CameraFrame).captured_at),
    )
    proc = start_camera(procs, router, "--source", str(video), "--loop")
    wait_for(lambda: frames.count >= 25, 60.0, f"25 frames:\n{proc.output()}")
    sub.undeclare()
    assert "playing it again from its start (--loop)" in proc.output()
    steps = np.diff(stamps[:20])
    assert np.all(steps > 0), "the timeline never goes back at the loop"
    assert np.allclose(steps[steps < 0.2], 0.05, atol=1e-3), "the file's own 20 fps"


def test_a_bad_calibration_file_is_refused_with_its_field(
    procs: Procs, router: Router, tmp_path: Path
) -> None:
    bad = tmp_path / "arena.json"
    bad.write_text(
        '{"format": "wart-arena-calibration", "version": 1, "image_size": [640, 480], '
        '"homography": [[1, 0], [0, 1]], "camera_height_mm": 1500}'
    )
    proc = start_camera(procs, router, "--source", "0", "--calibration", str(bad))
    assert proc.popen.wait(30) == 2
    assert "homography: must have shape [3, 3]" in proc.output()
    assert str(bad) in proc.output()


def tilted_recording(path: Path, robot: Robot) -> Path:
    """A 1280x720 video of maps/empty.json's arena from a camera 1.66 m up, tilted 18
    degrees, through a barrel lens (tests/kit/overhead_camera.py), k1 standing still."""
    camera = OverheadCamera(1000, 1000, default_layout(1000, 1000, ["k1"]), Lens(), Mount())
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), 15.0, (1280, 720))
    for _ in range(15):
        writer.write(camera.render({"k1": robot}))
    writer.release()
    return path


def test_a_tilted_camera_warns_without_its_lens_and_is_exact_with_it(
    router: Router,
    procs: Procs,
    engine: str,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    robot = Robot(300.0, 650.0, 0.7)
    video = tilted_recording(tmp_path / "arena.avi", robot)
    tracked = Latest(zsession, keys.world_tracked(router.realm, WORLD), TrackedPoses)
    bare = start_camera(procs, router, "--source", str(video), "--loop", "--auto-calibrate")
    wait_for(lambda: tracked.count >= 3, 60.0, f"tracking without the lens:\n{bare.output()}")
    assert "no lens intrinsics: the error grows with the camera's tilt (about 1" in bare.output()
    assert "--camera-height not given: 1500 mm assumed" in bare.output()
    bare.stop()

    board = BoardCamera(Lens(), BoardSpec(), seed=2)  # the lens, as a lab calibrates it
    collector = IntrinsicsCollector(BoardSpec())
    for rotation, translation in board.views(40, seed=2):
        collector.offer(board.render(rotation, translation), consecutive=False)
    cal = tmp_path / "arena.json"
    save_intrinsics(cal, collector.calibrate())
    seen = Latest(zsession, keys.world_tracked(router.realm, WORLD), TrackedPoses)
    lens = procs.start(
        "camera-lens",
        ["camera", "--world", WORLD, "--source", str(video), "--loop", "--auto-calibrate",
         "--calibration", str(cal), *router.net_args()],
    )  # fmt: skip

    def exact() -> bool:
        poses = seen.get()
        if not isinstance(poses, TrackedPoses) or not poses.robots:
            return False
        r = poses.robots[0]
        return math.hypot(r.x - robot.x, r.y - robot.y) < 1.0

    wait_for(exact, 60.0, f"k1 within 1 mm with the lens:\n{lens.output()}")
    said = lens.output()
    assert "solved from the reference markers with the lens's intrinsics" in said
    assert "no lens intrinsics" not in said


def test_markers_of_no_robot_are_said_once(
    router: Router,
    procs: Procs,
    engine: str,
    tmp_path: Path,
    alive_watch: AliveWatch,
    zsession: zenoh.Session,
) -> None:
    stray = Truth(tmp_path / "truth.json", {"k1": (300.0, 300.0, 0.0), "k7": (700.0, 700.0, 1.0)})
    try:
        tracked = Latest(zsession, keys.world_tracked(router.realm, WORLD), TrackedPoses)
        proc = start_camera(
            procs, router, "--source", f"synthetic:{stray.path}", "--auto-calibrate"
        )
        wait_for(lambda: tracked.count >= 20, 60.0, f"20 tracked frames:\n{proc.output()}")
        poses = tracked.get()
        assert isinstance(poses, TrackedPoses) and [r.agent for r in poses.robots] == ["k1"]
        assert proc.output().count("marker 7 belongs to no robot of this arena: ignored") == 1
    finally:
        stray.close()


def test_a_robot_added_after_the_camera_started_is_tracked_on_the_worlds_news(
    router: Router,
    procs: Procs,
    tmp_path: Path,
    alive_watch: AliveWatch,
    zsession: zenoh.Session,
) -> None:
    """The camera reads the world's robots from its snapshot. A robot added later (a
    Khepera plugged in, a teacher's edit) is announced on ``world/<w>/layout``, and the
    camera reads them again then: its own periodic check is an hour away here, so only
    the news can bring k2 in. (Before the camera listened, a robot added just after it
    started went untracked for 30 s: a multi-host run's real robot moved 0 mm.)"""
    identity = RegistryIdentity.generate()
    net = router.options(registry_key=identity.verify_key.hex()).as_args()
    world = ["engine", "--map", empty_map(tmp_path), "--world", WORLD, *net]
    engine = procs.start("engine", world)
    assert alive_watch.wait(keys.alive(router.realm, AliveKind.WORLD, WORLD), 60.0), engine.output()
    both = Truth(tmp_path / "truth.json", {"k1": (300.0, 300.0, 0.0), "k2": (700.0, 650.0, 1.0)})
    try:
        tracked = Latest(zsession, keys.world_tracked(router.realm, WORLD), TrackedPoses)
        source = f"synthetic:{both.path}"
        argv = ["--source", source, "--auto-calibrate", "--layout-check", "3600"]
        camera = start_camera(procs, router, *argv)

        def agents() -> list[str]:
            poses = tracked.get()
            return sorted(r.agent for r in poses.robots) if isinstance(poses, TrackedPoses) else []

        wait_for(lambda: agents() == ["k1"], 60.0, "k1 tracked")
        stray = "marker 2 belongs to no robot of this arena: ignored"
        wait_for(lambda: stray in camera.output(), 30.0, "k2's marker seen, of no robot yet")
        assert agents() == ["k1"]
        teacher = issue_session(identity, router.realm, "teacher", ["edit_map"])
        edit_key = keys.world_edit(router.realm, WORLD)
        add = WorldEdit(op=AddItem(section="agents", entry={"id": "k2", "x": 700, "y": 650}))
        ask(zsession, edit_key, add, EditResult, what="add k2", timeout=10.0, seal=teacher.seal)
        wait_for(
            lambda: agents() == ["k1", "k2"], 30.0, f"k2 tracked once added:\n{camera.output()}"
        )
        assert "markers k1=1, k2=2" in camera.output()
    finally:
        both.close()


def test_wart_camera_calibrate_saves_a_calibration_the_camera_then_uses(
    router: Router,
    procs: Procs,
    engine: str,
    truth: Truth,
    tmp_path: Path,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
) -> None:
    out = tmp_path / "arena.json"
    source = f"synthetic:{truth.path}"
    argv = ["camera", "calibrate", "--world", WORLD, "--source", source, "--out", str(out)]
    calibrate = procs.start("calibrate", [*argv, *router.net_args()])
    assert calibrate.popen.wait(60) == 0, calibrate.output()
    assert "calibrated 640x480 from the reference markers" in calibrate.output()
    tracked = Latest(zsession, keys.world_tracked(router.realm, WORLD), TrackedPoses)
    camera = start_camera(
        procs, router, "--source", f"synthetic:{truth.path}", "--calibration", str(out)
    )
    wait_for(
        lambda: tracked.count > 3, 60.0, f"tracking with the saved calibration:\n{camera.output()}"
    )
    argv = ["camera", "calibrate", "--world", WORLD, "--arena", "1000x1000"]
    argv += ["--source", str(tmp_path / "none.mp4"), "--out", str(out)]
    missing = procs.start("calibrate-missing", argv)
    assert missing.popen.wait(60) == 2
    assert "no video file at" in missing.output()
