"""The calibration file's fields, read with the field named when wrong; a file may hold the
camera's lens alone (``wart camera calibrate --intrinsics``) before the arena's floor."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from common.files import write_atomic
from common.tracking.intrinsics import Intrinsics, IntrinsicsError

FORMAT = "wart-arena-calibration"
VERSION = 1


class CalibrationError(ValueError):
    """A calibration that cannot be made or read; the message says what to do."""


def read_document(path: Path) -> Any:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CalibrationError(
            f"{path}: no calibration file there; make one with `wart camera calibrate`"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot be read ({exc})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"{path}: not JSON (line {exc.lineno}: {exc.msg})") from None


def check_format(data: Any) -> None:
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise CalibrationError(f'not an arena calibration (needs "format": "{FORMAT}")')
    if data.get("version") != VERSION:
        raise CalibrationError(f"version {data.get('version')!r} is not {VERSION}")


def matrix(
    data: dict[str, Any], name: str, shape: tuple[int, ...], optional: bool = False
) -> np.ndarray | None:
    value = data.get(name)
    if value is None and optional:
        return None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name}: must be numbers") from None
    if arr.shape != shape and not (name == "dist_coeffs" and arr.ndim == 1 and 4 <= arr.size <= 14):
        raise CalibrationError(f"{name}: must have shape {list(shape)}, got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{name}: must be finite numbers")
    return arr


def number(data: dict[str, Any], name: str) -> float | None:
    value = data.get(name)
    if value is None:
        return None
    if not isinstance(value, int | float) or isinstance(value, bool) or not math.isfinite(value):
        raise CalibrationError(f"{name}: must be a number, or null")
    return float(value)


def lens_of(data: dict[str, Any]) -> Intrinsics | None:
    """The intrinsics' report of a calibration file (None for a file from before it)."""
    report = data.get("intrinsics")
    if report is None:
        return None
    camera_matrix = matrix(data, "camera_matrix", (3, 3))
    dist_coeffs = matrix(data, "dist_coeffs", (5,))
    assert camera_matrix is not None and dist_coeffs is not None
    try:
        return Intrinsics.from_report(report, camera_matrix, dist_coeffs)
    except IntrinsicsError as exc:
        raise CalibrationError(str(exc)) from None


def read_intrinsics(path: Path) -> Intrinsics | None:
    """The camera's intrinsics a calibration file holds (with or without the arena's floor);
    None when it holds none. A missing or wrong file is a CalibrationError."""
    data = read_document(path)
    try:
        check_format(data)
        if data.get("camera_matrix") is None:
            return None
        lens = lens_of(data)
        if lens is not None:
            return lens
        camera_matrix = matrix(data, "camera_matrix", (3, 3))
        dist_coeffs = matrix(data, "dist_coeffs", (5,), optional=True)
        assert camera_matrix is not None
        size = data.get("image_size")
        if not (isinstance(size, list) and len(size) == 2):
            raise CalibrationError("image_size: must be [width, height] in whole pixels")
        return Intrinsics(
            (int(size[0]), int(size[1])),
            camera_matrix,
            np.zeros(5) if dist_coeffs is None else dist_coeffs,
        )
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None


def floor_calibrated(path: Path) -> bool:
    """Whether a calibration file holds the arena's floor (not only the lens)."""
    data = read_document(path)
    return not (isinstance(data, dict) and data.get("homography") is None)


def save_intrinsics(path: Path, lens: Intrinsics) -> None:
    """A calibration file with the camera's intrinsics only: the arena's floor is
    calibrated next, with them (`wart camera calibrate --world ... --out` the same file)."""
    document = {
        "format": FORMAT,
        "version": VERSION,
        "image_size": list(lens.image_size),
        "homography": None,
        "camera_matrix": lens.camera_matrix.tolist(),
        "dist_coeffs": np.asarray(lens.dist_coeffs).ravel().tolist(),
        "intrinsics": lens.report(),
    }
    write_atomic(path, (json.dumps(document, indent=1) + "\n").encode())


def notes_of(data: dict[str, Any]) -> tuple[str, ...]:
    value = data.get("notes", [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CalibrationError("notes: must be a list of sentences")
    return tuple(value)
