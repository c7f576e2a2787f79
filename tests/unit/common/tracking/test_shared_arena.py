"""Two cameras over one long arena, one per half: the reference markers along the seam
let each calibrate from the four it sees, and both find a robot on the seam alike."""

from __future__ import annotations

import math

import pytest

from common.tracking.calibration import CalibrationError, calibrate
from common.tracking.markers import (
    MarkerError,
    default_layout,
    parse_grid,
    reference_grid,
    robot_markers,
)
from common.tracking.synthetic import CameraModel, SyntheticCamera
from common.tracking.tracker import Tracker

WIDTH, HEIGHT = 2000.0, 1000.0
# Each camera hangs over its half and sees 200 mm past the seam (as the synthetic
# source's --synthetic-over 0,0,1100,1000 places it).
HALVES = {"left": 550.0, "right": 1450.0}


def half_camera(x_mm: float, grid: tuple[int, int]) -> SyntheticCamera:
    layout = default_layout(WIDTH, HEIGHT, ["k1"], grid=grid)
    # The view of 1100 x 1000 mm of a 2000 x 1000 arena: margin 1.12 x (1000/480)/(2000/640).
    model = CameraModel(x_mm=x_mm, y_mm=HEIGHT / 2, margin=1.12 * (1000 / 480) / (2000 / 640))
    return SyntheticCamera(WIDTH, HEIGHT, layout, model, blur_sigma_px=0.6, noise_sigma=2.0)


def test_a_grid_keeps_the_corner_ids_and_lays_the_others_along_the_seam() -> None:
    assert reference_grid(1000, 1000) == {
        46: (45, 45),
        47: (955, 45),
        48: (955, 955),
        49: (45, 955),
    }
    seam = reference_grid(WIDTH, HEIGHT, (3, 2))
    assert seam[46] == (45, 45) and seam[48] == (1955, 955)
    assert seam[45] == (1000, 45) and seam[44] == (1000, 955)
    # Robots keep kN = N below the floor's ids; k44 and k45 take free ones.
    ids = robot_markers(["k1", "k44", "k45"], references=len(seam))
    assert ids["k1"] == 1 and {ids["k44"], ids["k45"]} == {0, 2}
    assert default_layout(WIDTH, HEIGHT, ["k45"], grid=(3, 2)).robots == {"k45": 0}
    assert parse_grid("3X2") == (3, 2)
    for bad in ("3", "1x2", "6x2", "axb", "3x2x1"):
        with pytest.raises(MarkerError, match=r"COLUMNSxROWS|2 to 5"):
            parse_grid(bad)


def test_each_half_camera_calibrates_from_the_four_markers_it_sees() -> None:
    # Markers at the corners only: a camera over one half sees two, and says so.
    with pytest.raises(CalibrationError, match=r"saw \[46, 49\]"):
        camera = half_camera(HALVES["left"], (2, 2))
        calibrate(camera.render({}), camera.layout, camera_matrix=camera.camera_matrix)
    on_seam = (1000.0, 500.0, 0.7)
    found = {}
    for side, x in HALVES.items():
        camera = half_camera(x, (3, 2))
        cal = calibrate(camera.render({}), camera.layout, camera_matrix=camera.camera_matrix)
        assert cal.check_mm is not None and cal.check_mm < 2.0, cal.report()
        tracker = Tracker(camera.layout, cal)
        near = (700.0, 300.0, 0.0) if side == "left" else (1300.0, 700.0, 2.0)
        for i, pose in enumerate((on_seam, near)):
            seen = tracker.track(camera.render({"k1": pose}), captured_at=float(i))
            (p,) = seen.poses
            assert math.hypot(p.x - pose[0], p.y - pose[1]) < 2.0, (side, pose, p)
            if pose is on_seam:
                found[side] = (p.x, p.y)
    # Both see the robot on the seam within a millimetre of each other: one robot.
    assert math.dist(found["left"], found["right"]) < 1.5, found
