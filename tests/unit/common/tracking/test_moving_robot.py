"""A robot at a Khepera's top speed, smeared over about 7 px by a 1/25 s exposure, stays
tracked: the tracker reads it through its blur where its last fixes say it went. A robot
that is lost anyway is said once, with the reason."""

from __future__ import annotations

import math

import pytest

from common.tracking.calibration import ArenaCalibration, calibrate
from common.tracking.markers import MarkerLayout, default_layout
from common.tracking.tracker import Tracker
from tests.kit.overhead_camera import Effects, Hand, Lens, Mount, OverheadCamera, Robot

# Making the module's camera costs seconds of CPU: its tests share one
# worker (xdist group), which makes it once.
pytestmark = pytest.mark.one_worker

FPS = 15.0
LENS = Lens()


@pytest.fixture(scope="module")
def layout() -> MarkerLayout:
    return default_layout(1000, 1000, ["k1", "k2"])


@pytest.fixture(scope="module")
def camera(layout: MarkerLayout) -> OverheadCamera:
    return OverheadCamera(1000, 1000, layout, LENS, Mount(tilt_deg=18.0), seed=3)


@pytest.fixture(scope="module")
def calibration(camera: OverheadCamera, layout: MarkerLayout) -> ArenaCalibration:
    # The true lens here: the lens's calibration has tests of its own (test_intrinsics.py).
    return calibrate(
        camera.render({}), layout, camera_matrix=LENS.matrix, dist_coeffs=LENS.coefficients
    )


def test_a_robot_at_top_speed_stays_tracked(
    camera: OverheadCamera, layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    tracker = Tracker(layout, calibration, say=lambda _: None)
    speed, way = 320.0, math.radians(35)
    vx, vy = speed * math.cos(way), speed * math.sin(way)
    seen, errors = 0, []
    frames = 24
    for i in range(frames):
        t = i / FPS
        robot = Robot(250 + vx * t, 250 + vy * t, way + 0.3, vx, vy)
        effects = Effects(exposure_s=1 / 25, noise_grey=3.0, jpeg_quality=85)
        poses = tracker.track(camera.render({"k1": robot}, effects=effects), t).poses
        for pose in poses:
            seen += 1
            errors.append(math.hypot(pose.x - robot.x, pose.y - robot.y))
    assert seen >= frames - 1, f"{seen} of {frames} frames"
    assert max(errors) < 3.0


def test_a_covered_robot_is_said_lost_once_with_the_reason(
    camera: OverheadCamera, layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    said: list[str] = []
    tracker = Tracker(layout, calibration, say=said.append)
    robot = {"k2": Robot(600.0, 400.0, 1.0)}
    tracker.track(camera.render(robot), 0.0)
    for i in range(1, 20):  # a hand held over it for 1.3 s
        tracker.track(camera.render(robot, hands=[Hand(600.0, 400.0)]), i / FPS)
    tracker.track(camera.render(robot), 20 / FPS)
    lost = [s for s in said if "lost" in s]
    assert lost == [
        "k2 lost: not seen for 1.0 s since (600, 400) mm; it stood still: its marker is "
        "covered, or it was lifted"
    ]
    assert said[-1] == "k2 is seen again"


def test_a_robot_at_top_speed_is_found_from_its_first_frame_and_held_through_a_turn() -> None:
    """The case the bench missed: 25 degrees of tilt through a pincushion lens, the robot
    driving along the arena's y (the image's height, smeared along its marker's side),
    never read sharp: found among the unread outlines in its first frames, then held,
    also when it turns back at a wall (its last two fixes then point the wrong way)."""
    lens = Lens(k1=0.10, k2=-0.02, p1=-0.0006, p2=0.0004)
    mount = Mount(height_mm=1700.0, tilt_deg=25.0, roll_deg=-2.0, yaw_deg=8.0)
    layout = default_layout(1000, 1000, ["k3", "k4"])
    camera = OverheadCamera(1000, 1000, layout, lens, mount, seed=7)
    calibration = calibrate(
        camera.render({}), layout, camera_matrix=lens.matrix, dist_coeffs=lens.coefficients
    )
    tracker = Tracker(layout, calibration, say=lambda _: None)
    seen, errors, frames = 0, [], 20
    y, vy = 380.0, -320.0
    for i in range(frames):
        y += vy / FPS
        if y < 110.0:  # back from the wall
            y, vy = 220.0 - y, -vy
        robot = Robot(470.0 + 10.0 * i / FPS, y, 0.2, 10.0, vy)
        effects = Effects(exposure_s=1 / 25, defocus_px=0.6, noise_grey=3.0, jpeg_quality=85)
        for pose in tracker.track(camera.render({"k4": robot}, effects=effects), i / FPS).poses:
            seen += 1
            errors.append(math.hypot(pose.x - robot.x, pose.y - robot.y))
    assert seen >= frames - 1, f"{seen} of {frames} frames"
    assert max(errors) < 3.0


def test_a_robot_that_turned_at_a_wall_under_a_hand_is_read_again_once_uncovered(
    layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    """At top speed, covered for 0.6 s while it turns back at a wall: its last fixes then
    point the wrong way and the wide window around its last place is long past; its
    smeared marker is outlined by its core alone (under 0.6 of its side), and is read
    there once the hand lifts (the bench lost such a robot for 5 frames).

    Its own camera (the module's renders in whatever order the tests ran, and the noise
    with them): over twelve noise seeds this tracker read 7 to 9 of the 9 frames after
    the lift; on this camera (seed 3) the previous tracker missed the first 4."""
    camera = OverheadCamera(1000, 1000, layout, LENS, Mount(tilt_deg=18.0), seed=3)
    tracker = Tracker(layout, calibration, say=lambda _: None)
    x, y, vx, vy = 700.0, 400.0, 292.0, -131.0
    effects = Effects(exposure_s=1 / 25, defocus_px=0.6, noise_grey=3.0, jpeg_quality=85)
    read_after: list[bool] = []
    for i in range(22):
        x, y = x + vx / FPS, y + vy / FPS
        if x > 890.0:  # back from the wall
            x, vx = 1780.0 - x, -vx
        robot = Robot(x, y, 0.4, vx, vy)
        hands = [Hand(x, y)] if 4 <= i < 13 else []
        frame = camera.render({"k1": robot}, hands=hands, effects=effects)
        poses = tracker.track(frame, i / FPS).poses
        if i >= 13:
            read_after.append(any(math.hypot(p.x - x, p.y - y) < 3.0 for p in poses))
    assert sum(read_after) >= 7 and any(read_after[:2]), read_after
