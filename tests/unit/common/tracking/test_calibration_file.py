"""A calibration file: saved and read back whole; a missing or wrong one refused with
what to do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.tracking.calibration import ArenaCalibration, CalibrationError


def good() -> ArenaCalibration:
    h = np.array([[2.1, 0.01, -120.0], [0.0, -2.1, 1100.0], [0.0, 0.0, 1.0]])
    return ArenaCalibration(
        image_size=(640, 480), homography=h, camera_height_mm=1500.0, rms_mm=0.4
    )


def test_a_saved_calibration_reads_back_the_same(tmp_path: Path) -> None:
    path = tmp_path / "arena.json"
    good().save(path)
    back = ArenaCalibration.load(path)
    assert back.image_size == (640, 480)
    assert np.allclose(back.homography, good().homography)
    assert np.allclose(
        back.to_arena(np.array([[100.0, 200.0]])), good().to_arena(np.array([[100.0, 200.0]]))
    )


def test_a_missing_file_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(
        CalibrationError, match=r"no calibration file there; make one with `wart camera calibrate`"
    ):
        ArenaCalibration.load(tmp_path / "nope.json")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="wart-map"), "not an arena calibration"),
        (lambda d: d.update(homography=[[1, 2], [3, 4]]), r"homography: must have shape \[3, 3\]"),
        (lambda d: d.update(homography=[[0, 0, 0]] * 3), "invertible 3x3"),
        (lambda d: d.update(camera_height_mm="high"), "camera_height_mm: must be a number"),
        (lambda d: d.update(camera_height_mm=5), "camera_height_mm must be 100 to 20000"),
        (lambda d: d.update(image_size=[640]), r"image_size: must be \[width, height\]"),
        (lambda d: d.update(version=7), "version 7 is not 1"),
    ],
)
def test_a_wrong_file_names_the_field(tmp_path: Path, edit, message: str) -> None:  # type: ignore[no-untyped-def]
    data = good().to_json()
    edit(data)
    path = tmp_path / "arena.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationError, match=message) as err:
        ArenaCalibration.load(path)
    assert str(path) in str(err.value)


def test_text_that_is_not_json_names_the_line(tmp_path: Path) -> None:
    path = tmp_path / "arena.json"
    path.write_text('{\n "format": "wart-arena-calibration",\n oops\n}')
    with pytest.raises(CalibrationError, match=r"not JSON \(line 3"):
        ArenaCalibration.load(path)
