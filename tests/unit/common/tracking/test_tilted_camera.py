"""A tilted camera with a distorting lens, rendered by a camera that is not the tracker's
(tests/kit/overhead_camera.py): with the lens calibrated from a ChArUco board the robots
are found without bias; without it the camera says its error grows with its tilt."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.tracking.calibration import CHECK_WARN_MM, ArenaCalibration, calibrate
from common.tracking.intrinsics import BoardSpec, Intrinsics, IntrinsicsCollector
from common.tracking.markers import MarkerLayout, default_layout
from common.tracking.tracker import Tracker
from services.camera.main import main
from tests.kit.overhead_camera import (
    BoardCamera,
    Effects,
    Lens,
    Mount,
    OverheadCamera,
    Robot,
)

# Making the module's camera and its lens calibration costs seconds of CPU: its tests
# share one worker (xdist group), which makes them once.
pytestmark = pytest.mark.one_worker

AGENTS = ["k1", "k2", "k3", "k4"]
LENS = Lens()  # 1280x720, barrel distortion of 7 to 12 px at the arena's corners
MOUNT = Mount(height_mm=1660.0, tilt_deg=18.0, roll_deg=1.5)


@pytest.fixture(scope="module")
def layout() -> MarkerLayout:
    return default_layout(1000, 1000, AGENTS)


@pytest.fixture(scope="module")
def camera(layout: MarkerLayout) -> OverheadCamera:
    return OverheadCamera(1000, 1000, layout, LENS, MOUNT, seed=5)


@pytest.fixture(scope="module")
def lens() -> Intrinsics:
    board = BoardCamera(LENS, BoardSpec(), seed=6)
    collector = IntrinsicsCollector(BoardSpec())
    for rotation, translation in board.views(50, seed=6):
        collector.offer(board.render(rotation, translation), consecutive=False)
    return collector.calibrate()


def errors(
    camera: OverheadCamera, layout: MarkerLayout, cal: ArenaCalibration, frames: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Standing robots at random places and headings: each pose's offset (mm) and its
    heading's error (degrees)."""
    rng = np.random.default_rng(9)
    out, turns = [], []
    for i in range(frames):
        robots = {
            agent: Robot(
                float(rng.uniform(120, 880)),
                float(rng.uniform(120 + 190 * k, 270 + 190 * k)),
                float(rng.uniform(-math.pi, math.pi)),
            )
            for k, agent in enumerate(AGENTS)
        }
        frame = camera.render(robots, effects=Effects(noise_grey=3.0, jpeg_quality=85))
        for pose in Tracker(layout, cal).detect_poses(frame, float(i)):
            truth = robots[pose.agent]
            out.append((pose.x - truth.x, pose.y - truth.y))
            turns.append(math.degrees(abs(math.remainder(pose.heading - truth.heading, math.tau))))
    assert len(out) == frames * len(AGENTS)
    return np.array(out), np.array(turns)


def test_with_the_lens_calibrated_a_tilted_camera_tracks_without_bias(
    camera: OverheadCamera, layout: MarkerLayout, lens: Intrinsics
) -> None:
    cal = calibrate(
        camera.render({}),
        layout,
        camera_matrix=lens.camera_matrix,
        dist_coeffs=lens.dist_coeffs,
        lens=lens,
    )
    # The camera's pose, solved from the four reference markers.
    assert cal.camera_height_mm == pytest.approx(MOUNT.height_mm, rel=0.01)
    assert cal.tilt_deg == pytest.approx(MOUNT.tilt_deg, abs=0.5)
    assert cal.camera_xy_mm is not None
    assert math.dist(cal.camera_xy_mm, camera.centre[:2]) < 15.0
    # Honest error: each reference marker predicted from the other three.
    assert cal.check_mm is not None and cal.check_mm < CHECK_WARN_MM
    assert "mm rms predicting each reference marker from the others" in cal.report()
    assert cal.warnings() == []
    off, turns = errors(camera, layout, cal)
    distance = np.linalg.norm(off, axis=1)
    assert np.linalg.norm(off.mean(axis=0)) < 1.0, off.mean(axis=0)
    assert float(np.median(distance)) < 1.0
    assert float(distance.max()) < 3.0
    # Headings from the marker's whole pattern, not its outline alone (from the outline:
    # 0.20 deg at the median on these frames).
    assert float(np.median(turns)) < 0.1 and float(turns.max()) < 0.5, turns


def test_without_the_lens_the_camera_says_its_error_grows_with_its_tilt(
    camera: OverheadCamera, layout: MarkerLayout
) -> None:
    cal = calibrate(camera.render({}), layout, camera_height_mm=MOUNT.height_mm)
    assert cal.tilt_deg == pytest.approx(MOUNT.tilt_deg, abs=2.0)
    off_check, warning = cal.warnings()
    assert cal.check_mm is not None and cal.check_mm > CHECK_WARN_MM
    assert f"the calibration is {cal.check_mm:.1f} mm off on reference markers" in off_check
    assert "error grows with the camera's tilt (about 1" in warning
    assert "wart camera calibrate --intrinsics" in warning
    assert "estimated from the floor's homography" in cal.report()
    # The parallax is corrected toward the floor point under the camera (estimated), not
    # under the image's centre: no longer a bias of a centimetre along the tilt.
    off, _ = errors(camera, layout, cal, frames=4)
    assert abs(float(off[:, 1].mean())) < 3.0


def test_a_camera_height_that_disagrees_with_the_markers_is_said_with_both_numbers(
    camera: OverheadCamera, layout: MarkerLayout, lens: Intrinsics
) -> None:
    frame = camera.render({})
    solved = calibrate(
        frame,
        layout,
        camera_height_mm=1000.0,
        camera_matrix=lens.camera_matrix,
        dist_coeffs=lens.dist_coeffs,
    )
    assert solved.camera_height_mm == pytest.approx(1660.0, rel=0.01)
    assert any(
        w.startswith("--camera-height 1000 mm disagrees with the 16") and "mm the reference" in w
        for w in solved.warnings()
    ), solved.warnings()
    guessed = calibrate(frame, layout, camera_height_mm=9000.0)
    assert "no camera 9000 mm up sees the floor as this one does" in guessed.warnings()[0]


@pytest.mark.parametrize("height", ["50", "20000", "nan", "high"])
def test_an_absurd_camera_height_is_refused_by_the_command(
    height: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as refused:
        main(["--world", "w1", "--source", "0", "--camera-height", height])
    assert refused.value.code == 2
    said = capsys.readouterr().err
    assert "argument --camera-height: the camera's height above the floor, mm:" in said
    assert "must be 300 to 10000" in said or "not a number" in said
