"""Overhead tracking on frames rendered from known poses: where the robots are, and
what the tracker holds back (unknown markers, occlusions, jumps), said once."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from common.tracking.calibration import ArenaCalibration, CalibrationError, calibrate
from common.tracking.markers import MarkerError, MarkerLayout, default_layout
from common.tracking.synthetic import CameraModel, SyntheticCamera
from common.tracking.tracker import Tracker

AGENTS = ["k0", "k1", "k2"]


def angle_error(a: float, b: float) -> float:
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


@pytest.fixture(scope="module")
def layout() -> MarkerLayout:
    return default_layout(1000, 1000, AGENTS)


# One camera a test: its sensor noise is seeded, and a camera shared by the module gave
# each test the noise of however many frames the tests before it on that worker had
# rendered (a CI run's order read k0 at 800, 800 as marker 37; 29 of 200 such frames
# are misread at this noise).
@pytest.fixture
def camera(layout: MarkerLayout) -> SyntheticCamera:
    return SyntheticCamera(1000, 1000, layout, blur_sigma_px=0.7, noise_sigma=3.0, seed=1)


@pytest.fixture(scope="module")
def calibration(layout: MarkerLayout) -> ArenaCalibration:
    camera = SyntheticCamera(1000, 1000, layout, blur_sigma_px=0.7, noise_sigma=3.0, seed=1)
    return calibrate(camera.render({}), layout, camera_height_mm=camera.model.height_mm)


def test_robots_are_found_within_millimetres_and_a_degree(
    camera: SyntheticCamera, layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    rng = np.random.default_rng(7)
    errors_mm, errors_deg = [], []
    for i in range(12):
        poses = {
            "k0": (rng.uniform(150, 350), rng.uniform(150, 850), rng.uniform(-3, 3)),
            "k1": (rng.uniform(420, 580), rng.uniform(150, 850), rng.uniform(-3, 3)),
            "k2": (rng.uniform(650, 850), rng.uniform(150, 850), rng.uniform(-3, 3)),
        }
        seen = Tracker(layout, calibration).track(camera.render(poses), captured_at=float(i))
        assert sorted(p.agent for p in seen.poses) == AGENTS
        for p in seen.poses:
            x, y, heading = poses[p.agent]
            assert p.at == float(i)
            errors_mm.append(math.hypot(p.x - x, p.y - y))
            errors_deg.append(math.degrees(angle_error(p.heading, heading)))
    # The bench's targets are p50 3 mm / 1 degree and p99 8 mm / 3 degrees.
    assert max(errors_mm) < 8.0, errors_mm
    assert max(errors_deg) < 3.0, errors_deg
    assert float(np.median(errors_mm)) < 3.0
    assert float(np.median(errors_deg)) < 1.0


def test_a_tilted_distorting_camera_is_corrected_with_its_intrinsics(layout: MarkerLayout) -> None:
    camera = SyntheticCamera(1000, 1000, layout, CameraModel(tilt_deg=6, k1=-0.12), seed=2)
    cal = calibrate(
        camera.render({}),
        layout,
        camera_matrix=camera.camera_matrix,
        dist_coeffs=camera.dist_coeffs,
    )
    assert cal.camera_height_mm == pytest.approx(camera.model.height_mm, rel=0.02)
    poses = {"k0": (200.0, 300.0, 0.5), "k1": (800.0, 750.0, -2.0)}
    seen = Tracker(layout, cal).track(camera.render(poses), 0.0)
    assert {p.agent for p in seen.poses} == {"k0", "k1"}
    for p in seen.poses:
        assert math.hypot(p.x - poses[p.agent][0], p.y - poses[p.agent][1]) < 4.0


def test_an_occluded_marker_is_not_reported(
    camera: SyntheticCamera, layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    poses = {"k0": (300.0, 300.0, 0.0), "k1": (700.0, 700.0, 1.0)}
    seen = Tracker(layout, calibration).track(camera.render(poses, hidden=["k1"]), 0.0)
    assert [p.agent for p in seen.poses] == ["k0"]


def test_a_marker_of_no_robot_is_ignored_and_said_once(
    camera: SyntheticCamera, calibration: ArenaCalibration
) -> None:
    # The camera draws k2's marker (id 2), but this arena's layout knows only k0.
    small = default_layout(1000, 1000, ["k0"])
    said: list[str] = []
    tracker = Tracker(small, calibration, say=said.append)
    frame = camera.render({"k0": (300.0, 500.0, 0.0), "k2": (700.0, 500.0, 0.0)})
    for t in range(5):
        seen = tracker.track(frame, float(t))
        assert [p.agent for p in seen.poses] == ["k0"]
        assert seen.unknown_markers == (2,)
    assert said == ["marker 2 belongs to no robot of this arena: ignored"]


def test_a_jump_is_held_back_until_it_holds(
    camera: SyntheticCamera, layout: MarkerLayout, calibration: ArenaCalibration
) -> None:
    said: list[str] = []
    tracker = Tracker(layout, calibration, confirm_frames=3, say=said.append)
    here, there = (
        camera.render({"k0": (200.0, 200.0, 0.0)}),
        camera.render({"k0": (800.0, 800.0, 0.0)}),
    )
    assert [p.agent for p in tracker.track(here, 0.00).poses] == ["k0"]
    # 850 mm in 40 ms: no Khepera drives that fast; the first two frames are held back.
    assert tracker.track(there, 0.04).held_back == ("k0",)
    assert tracker.track(there, 0.08).held_back == ("k0",)
    moved = tracker.track(there, 0.12)
    assert [round(p.x, -1) for p in moved.poses] == [800.0]
    assert len([s for s in said if "jumped" in s]) == 1
    # Said where it is now, to the millimetre the tracker reads (the frame's noise moves it).
    where = [re.search(r"was moved to \((\d+), (\d+)\) mm", s) for s in said]
    (x, y) = next((float(m[1]), float(m[2])) for m in where if m)
    assert abs(x - 800) <= 3 and abs(y - 800) <= 3, said


def test_calibration_needs_the_reference_markers(layout: MarkerLayout) -> None:
    blank = np.full((480, 640, 3), 200, np.uint8)
    with pytest.raises(
        CalibrationError, match=r"reference markers \[46, 47, 48, 49\] in view; saw none"
    ):
        calibrate(blank, layout, camera_height_mm=1500)


def test_a_layout_with_an_id_twice_is_refused() -> None:
    with pytest.raises(MarkerError, match=r"ids \[46\] are used twice"):
        MarkerLayout(robots={"k0": 46}, reference={46: (0, 0), 47: (1, 0), 48: (1, 1), 49: (0, 1)})
