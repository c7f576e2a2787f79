"""A real robot's pose in its world: odometry corrected by the arena camera.

The emulated Khepera runs in the test (its true pose is known) with slipping
wheels, so odometry drifts as a real robot's does; the bridge reads it over the
serial protocol on a pty; ``wart camera`` renders the emulator's true poses as a
synthetic camera and tracks the marker. The world's frames must follow the true
pose within millimetres where odometry alone drifts far, and a robot the camera
loses is "not seen", never a guess.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import TrackedPoses, WorldFrame, WorldSnapshot, decode
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.odometry import Odometry
from services.bridge.simbody import SimBody
from services.lab.supervisor import AliveWatch
from tests.conftest import REPO, Proc, Procs, Router, wait_for
from tests.integration.test_camera import Truth
from tests.kit.waits import Latest

WORLD = "real1"
AGENT = "k1"


@pytest.fixture
def truth(tmp_path: Path) -> Path:
    return tmp_path / "truth.json"


@pytest.fixture
def body(truth: Path) -> Iterator[SimBody]:
    with SimBody.from_map(REPO / "maps" / "empty.json", seed=2, slip=0.03, truth=truth) as sim:
        yield sim


@pytest.fixture
def emulator(body: SimBody, tmp_path: Path) -> Iterator[KheperaEmulator]:
    with KheperaEmulator(body, EmulatorOptions(link_path=str(tmp_path / "khepera0"))) as emu:
        yield emu


def frame_pose(frames: Latest) -> tuple[float, float, float] | None:
    frame = frames.get()
    if not isinstance(frame, WorldFrame):
        return None
    x, y, h = frame.poses.to_numpy()[0]
    return float(x), float(y), float(h)


def pose_from(session: zenoh.Session, realm: str) -> str:
    for reply in session.get(keys.world_snapshot(realm, WORLD), timeout=10.0):
        if reply.ok is not None:
            snap = decode(reply.ok.payload, WorldSnapshot)
            if isinstance(snap, WorldSnapshot) and snap.agents:
                return snap.agents[0].pose_from
    return ""


def start_bridge_and_camera(
    router: Router, procs: Procs, alive_watch: AliveWatch, port: str, source: str, *extra: str
) -> tuple[Proc, Proc]:
    """The bridge on the emulated robot's pty, then a camera over its world."""
    net = router.net_args()
    robot = f"{port}={AGENT}@500,500,0"
    bridge = procs.start("bridge", ["bridge", "--world", WORLD, "--port", robot, *net])
    assert alive_watch.wait(keys.alive(router.realm, AliveKind.WORLD, WORLD), 30.0), bridge.output()
    argv = ["camera", "--world", WORLD, "--source", source, "--auto-calibrate", *extra, *net]
    return bridge, procs.start("camera", argv)


def test_the_camera_holds_a_slipping_robot_to_its_true_pose(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    emulator: KheperaEmulator,
    body: SimBody,
    truth: Path,
) -> None:
    realm = router.realm
    bridge, camera = start_bridge_and_camera(
        router, procs, alive_watch, emulator.port, f"synthetic:{truth}", "--fps", "15"
    )
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    tracked = Latest(zsession, keys.world_tracked(realm, WORLD), TrackedPoses)
    wait_for(lambda: tracked.count > 5, 90.0, f"the camera tracking:\n{camera.output()}")
    wait_for(lambda: pose_from(zsession, realm) == "tracked", 20.0, "poses from the camera")

    # Drive circles for 40 s (about 3 m), as odometry alone would see them too.
    odometry = Odometry(0.08, 53.0)
    odometry.set_pose(odometry.pose.__class__(500.0, 500.0, 0.0))
    odometry.update(*body.counters(), time.monotonic())
    body.set_speeds(8, 12)
    errors, drift = [], 0.0
    end = time.monotonic() + 40.0
    while time.monotonic() < end:
        time.sleep(0.25)  # a sampling period of the test's own odometry, not a wait
        odo = odometry.update(*body.counters(), time.monotonic())
        x, y, _ = body.pose()
        drift = math.hypot(odo.x - x, odo.y - y)
        shown = frame_pose(frames)
        if shown is not None:
            errors.append(math.hypot(shown[0] - x, shown[1] - y))
    body.set_speeds(0, 0)
    time.sleep(0.5)  # the last frames after the stop
    x, y, heading = body.pose()
    final = frame_pose(frames)
    assert final is not None
    final_error = math.hypot(final[0] - x, final[1] - y)
    assert drift > 30.0, f"odometry alone drifted only {drift:.1f} mm: the test proves nothing"
    assert final_error < 10.0, (final, (x, y, heading), drift)
    assert sorted(errors)[len(errors) // 2] < 10.0  # the median while driving
    assert "poses from the camera" in bridge.output()


def test_a_robot_the_camera_loses_is_not_seen_and_the_world_says_so(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    alive_watch: AliveWatch,
    emulator: KheperaEmulator,
    body: SimBody,
    truth: Path,
    tmp_path: Path,
) -> None:
    realm = router.realm
    net = router.net_args()
    bridge, camera = start_bridge_and_camera(
        router, procs, alive_watch, emulator.port, f"synthetic:{truth}"
    )
    wait_for(
        lambda: pose_from(zsession, realm) == "tracked",
        90.0,
        f"poses from the camera:\n{camera.output()}",
    )
    # The camera dies: the world falls back to odometry, and says so.
    camera.kill9()
    wait_for(lambda: pose_from(zsession, realm) == "odometry", 20.0, "poses from odometry")
    assert "poses from odometry" in bridge.output()
    # A live camera that does not see the robot (a hand over its marker): "not seen",
    # where it was last trusted, while its odometry runs off.
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: frame_pose(frames) is not None, 10.0, "a frame")
    last = frame_pose(frames)
    assert last is not None
    hidden = Truth(tmp_path / "hidden.json", {})
    try:
        procs.start(
            "camera2",
            [
                "camera",
                "--world",
                WORLD,
                "--source",
                f"synthetic:{hidden.path}",
                "--auto-calibrate",
                *net,
            ],
        )
        wait_for(lambda: pose_from(zsession, realm) == "not seen", 90.0, "the robot not seen")
        body.set_speeds(20, 20)  # it drives on, unseen
        time.sleep(1.0)  # a second of driving the world must not show
        body.set_speeds(0, 0)
        shown = frame_pose(frames)
        assert shown is not None and math.hypot(shown[0] - last[0], shown[1] - last[1]) < 15.0
        assert "k1 is not seen by the camera" in bridge.output()
    finally:
        hidden.close()
