"""The lens calibrated as a lab does it: a ChArUco board shown to a camera that is not ours
(tests/kit/overhead_camera.py), views kept or refused as ROS's calibrator would, OpenCV's
solution saved with its uncertainty beside the arena's calibration."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from common.tracking.calibration import (
    ArenaCalibration,
    CalibrationError,
    read_intrinsics,
    save_intrinsics,
)
from common.tracking.intrinsics import BoardSpec, Intrinsics, IntrinsicsCollector, IntrinsicsError
from services.camera.calibrate import intrinsics_main
from services.camera.main import main
from tests.kit.overhead_camera import BoardCamera, Effects, Lens

# Rendering the module's 50 board views costs seconds of CPU: its tests share one
# worker (xdist group), which renders them once.
pytestmark = pytest.mark.one_worker

LENS = Lens()  # 1280x720, barrel distortion


@pytest.fixture(scope="module")
def board_camera() -> BoardCamera:
    return BoardCamera(LENS, BoardSpec(), seed=4)


@pytest.fixture(scope="module")
def collected(board_camera: BoardCamera) -> IntrinsicsCollector:
    collector = IntrinsicsCollector(BoardSpec())
    for rotation, translation in board_camera.views(50, seed=3):
        collector.offer(board_camera.render(rotation, translation), consecutive=False)
    return collector


def test_the_lens_is_recovered_within_its_stated_uncertainty(
    collected: IntrinsicsCollector,
) -> None:
    lens = collected.calibrate()
    assert collected.enough
    assert lens.reprojection_px < 0.3
    truth = {
        "fx": LENS.fx, "fy": LENS.fy, "cx": LENS.cx, "cy": LENS.cy,
        "k1": LENS.k1, "k2": LENS.k2, "p1": LENS.p1, "p2": LENS.p2,
    }  # fmt: skip
    found = {
        "fx": lens.camera_matrix[0, 0], "fy": lens.camera_matrix[1, 1],
        "cx": lens.camera_matrix[0, 2], "cy": lens.camera_matrix[1, 2],
        "k1": lens.dist_coeffs[0], "k2": lens.dist_coeffs[1],
        "p1": lens.dist_coeffs[2], "p2": lens.dist_coeffs[3],
    }  # fmt: skip
    for name, value in truth.items():
        sd = lens.std[name]
        assert 0 < sd < 0.01 * max(abs(value), 1.0), name
        # OpenCV's standard deviations are honest: the truth within 5 of them (or a hair).
        assert abs(found[name] - value) < max(5 * sd, 1e-4), (name, found[name], value, sd)


def test_coverage_is_shown_as_ross_bars_and_near_duplicates_are_refused(
    board_camera: BoardCamera,
) -> None:
    collector = IntrinsicsCollector(BoardSpec())
    rotation, translation = board_camera.pose_toward(640, 360, 900, 10, -5, 0)
    assert collector.offer(board_camera.render(rotation, translation), consecutive=False).kept
    again = collector.offer(board_camera.render(rotation, translation + 3), consecutive=False)
    assert (again.kept, again.reason) == (False, "near-duplicate of a view kept")
    assert collector.progress().startswith("x [") and "1 views" in collector.progress()
    assert not collector.enough
    with pytest.raises(IntrinsicsError, match="at least 8 are needed"):
        collector.calibrate()


def test_a_moving_board_and_a_blurred_one_are_refused(board_camera: BoardCamera) -> None:
    collector = IntrinsicsCollector(BoardSpec())
    rotation, translation = board_camera.pose_toward(500, 300, 800, 20, 0, 5)
    collector.offer(board_camera.render(rotation, translation))
    moved = collector.offer(board_camera.render(rotation, translation + np.array([25.0, 0.0, 0.0])))
    assert moved.reason == "board moving"
    rotation, translation = board_camera.pose_toward(640, 360, 650, -10, 15, 0)
    soft = board_camera.render(rotation, translation, Effects(exposure_s=0, defocus_px=2.0))
    assert collector.offer(soft, consecutive=False).reason == "blurred"


def test_intrinsics_are_saved_with_their_report_and_old_files_still_load(
    collected: IntrinsicsCollector, tmp_path: Path
) -> None:
    lens = collected.calibrate()
    path = tmp_path / "arena.json"
    save_intrinsics(path, lens)
    back = read_intrinsics(path)
    assert isinstance(back, Intrinsics) and back.views == lens.views
    assert np.allclose(back.camera_matrix, lens.camera_matrix)
    assert back.std["k1"] == pytest.approx(lens.std["k1"])
    with pytest.raises(CalibrationError, match="intrinsics but not the arena's floor yet"):
        ArenaCalibration.load(path)
    old = tmp_path / "old.json"
    old.write_text(
        json.dumps(
            {
                "format": "wart-arena-calibration",
                "version": 1,
                "image_size": [640, 480],
                "homography": [[2, 0, 0], [0, -2, 1000], [0, 0, 1]],
                "camera_height_mm": 1500,
            }
        )
    )
    assert ArenaCalibration.load(old).lens is None and read_intrinsics(old) is None


def test_wart_camera_calibrate_intrinsics_over_a_folder_of_photos(
    board_camera: BoardCamera, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    photos = tmp_path / "board"
    photos.mkdir()
    for i, (rotation, translation) in enumerate(board_camera.views(24, seed=11)):
        cv2.imwrite(str(photos / f"{i:02}.png"), board_camera.render(rotation, translation))
    out = tmp_path / "arena.json"
    assert intrinsics_main(["--source", str(photos), "--out", str(out)], "cal") == 0
    said = capsys.readouterr().out
    assert "kept; x [" in said and "skew [" in said
    assert "24 frames" in said and "reprojection" in said and f"saved to {out}" in said
    lens = read_intrinsics(out)
    assert lens is not None and abs(lens.camera_matrix[0, 0] - LENS.fx) < 3.0


def test_a_camera_given_the_lens_only_is_told_to_calibrate_the_floor(
    collected: IntrinsicsCollector, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "arena.json"
    save_intrinsics(path, collected.calibrate())
    argv = ["--world", "w1", "--source", "0", "--calibration", str(path)]
    assert main(argv) == 2
    assert "holds the lens only: add --auto-calibrate" in capsys.readouterr().err
