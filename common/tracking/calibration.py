"""From image pixels to arena millimetres: a homography set up once from the reference markers.

``calibrate`` finds the four reference markers in one frame and fits the floor's
homography to their 16 corners; ``ArenaCalibration`` maps points both ways and
corrects the parallax of a marker above the floor (the camera sees a robot's top
plate pushed outward from the point under it). With the camera's intrinsics
(OpenCV's pinhole model) the markers' corners are undistorted, the camera's
full pose (height, tilt and roll) comes from the reference markers
(``solvePnP``) and a marker lies where its own ray meets the plane at its
height. Without, the camera's pose is estimated from the homography and the
``camera_height_mm`` the lab measured (square pixels, centred, no distortion):
its error grows with its tilt and its lens, and it says so. Saved as a small
JSON file; a missing or wrong file is refused with the field named.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from common.files import write_atomic
from common.tracking.calibration_file import (
    FORMAT,
    VERSION,
    CalibrationError,
    check_format,
    floor_calibrated,
    lens_of,
    matrix,
    notes_of,
    number,
    read_document,
    read_intrinsics,
    save_intrinsics,
)
from common.tracking.geometry import CameraPose, pose_from_homography, solve_pose
from common.tracking.intrinsics import Intrinsics
from common.tracking.markers import MarkerLayout, corners_mm, dictionary

MIN_REFERENCE_MARKERS = 3
# The leave-one-out error above which the calibration warns. Each reference marker is
# predicted from the other three, out beyond their triangle: an upper bound for a robot
# inside the arena (measured on tests/kit/overhead_camera.py at 18 deg with the lens:
# 1 to 3 mm here, 0.2 mm p50 on robots; without the lens 11.5 mm here, 4.6 mm on robots).
CHECK_WARN_MM = 5.0
HEIGHT_TOLERANCE = 0.05  # --camera-height against the height the lens and markers imply
FIELD_OF_VIEW_DEG = (25.0, 130.0)  # the lenses overhead cameras have
# Made here, read from here by callers: the file's own module only parses.
__all__ = [
    "FORMAT",
    "VERSION",
    "ArenaCalibration",
    "CalibrationError",
    "calibrate",
    "detect",
    "detect_all",
    "floor_calibrated",
    "read_intrinsics",
    "reference_points",
    "save_intrinsics",
]


@dataclass(frozen=True)
class ArenaCalibration:
    """The floor's homography (image px -> arena mm) and what corrects it.

    ``camera_matrix`` and ``dist_coeffs`` (OpenCV's pinhole model) are optional:
    with them, detected corners are undistorted before they are mapped.
    """

    image_size: tuple[int, int]
    homography: np.ndarray  # 3x3, undistorted image px -> arena mm, floor plane
    camera_height_mm: float
    rms_mm: float = 0.0
    camera_matrix: np.ndarray | None = None
    dist_coeffs: np.ndarray | None = None
    # The floor point under the camera; None: under the image's centre (straight down).
    camera_xy_mm: tuple[float, float] | None = None
    # Where camera_matrix and dist_coeffs came from (`wart camera calibrate --intrinsics`).
    lens: Intrinsics | None = None
    # Arena -> camera axes, solved with the intrinsics: each marker's own ray is then used.
    rotation: np.ndarray | None = None
    # The optical axis' angle from straight down: solved, or estimated without intrinsics.
    tilt_deg: float | None = None
    # The error on reference points the fit did not use (leave-one-out), mm.
    check_mm: float | None = None
    # What the calibration found doubtful when it was made (said again on every start).
    notes: tuple[str, ...] = ()
    # The camera's pose when solved with the intrinsics (made from the fields above).
    pose: CameraPose | None = field(init=False, default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        h = np.asarray(self.homography, dtype=np.float64)
        if h.shape != (3, 3) or not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-12:
            raise CalibrationError("homography must be an invertible 3x3 matrix of numbers")
        object.__setattr__(self, "homography", h)
        if not (100.0 <= self.camera_height_mm <= 20_000.0):
            raise CalibrationError(
                f"camera_height_mm must be 100 to 20000 (the camera's height above the "
                f"floor); got {self.camera_height_mm}"
            )
        w, hgt = self.image_size
        if not (16 <= w <= 8192 and 16 <= hgt <= 8192):
            raise CalibrationError(f"image_size must be 16 to 8192 pixels a side; got {w}x{hgt}")
        if self.camera_xy_mm is None:
            ground = self._floor(np.array([[w / 2.0, hgt / 2.0]]))[0]
        else:
            ground = np.array(self.camera_xy_mm, dtype=np.float64)
        object.__setattr__(self, "_ground", ground)
        object.__setattr__(self, "_maps", None)
        pose = None
        if self.rotation is not None and self.camera_matrix is not None:
            centre = np.array([ground[0], ground[1], self.camera_height_mm])
            pose = CameraPose(np.asarray(self.rotation, dtype=np.float64), centre)
        object.__setattr__(self, "pose", pose)

    @property
    def has_intrinsics(self) -> bool:
        return self.camera_matrix is not None

    # -- mapping

    def undistort_frame(self, frame: np.ndarray) -> np.ndarray:
        """The frame as an ideal pinhole camera would see it (itself without intrinsics)."""
        if self.camera_matrix is None or self.dist_coeffs is None:
            return frame
        maps = self._maps  # type: ignore[attr-defined]
        if maps is None:
            maps = cv2.initUndistortRectifyMap(
                self.camera_matrix,
                self.dist_coeffs,
                None,
                self.camera_matrix,
                self.image_size,
                cv2.CV_16SC2,
            )
            object.__setattr__(self, "_maps", maps)
        return cv2.remap(frame, maps[0], maps[1], cv2.INTER_LINEAR)

    def undistort_points(self, pixels: np.ndarray) -> np.ndarray:
        """Detected pixels as an ideal pinhole camera would see them (themselves without
        intrinsics): cheaper than undistorting the frame, and exact at each corner."""
        if self.camera_matrix is None or self.dist_coeffs is None:
            return np.asarray(pixels, dtype=np.float64)
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        ideal = cv2.undistortPoints(pts, self.camera_matrix, self.dist_coeffs, P=self.camera_matrix)
        return np.asarray(ideal, dtype=np.float64).reshape(-1, 2)

    def _floor(self, pixels: np.ndarray) -> np.ndarray:
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        return np.asarray(cv2.perspectiveTransform(pts, self.homography)).reshape(-1, 2)

    def to_arena(self, pixels: np.ndarray, height_mm: float = 0.0) -> np.ndarray:
        """Arena mm of (undistorted) image points lying ``height_mm`` above the floor."""
        pose = self.pose
        if pose is not None and self.camera_matrix is not None:
            return pose.to_plane(self.camera_matrix, pixels, height_mm)
        floor = self._floor(pixels)
        if height_mm == 0.0:
            return floor
        ground: np.ndarray = self._ground  # type: ignore[attr-defined]
        return (
            ground + (floor - ground) * (self.camera_height_mm - height_mm) / self.camera_height_mm
        )

    def to_frame(self, arena_mm: np.ndarray, height_mm: float = 0.0) -> np.ndarray:
        """Pixels in the frame as recorded (distorted) of arena points ``height_mm`` up:
        where to look for a marker the tracker expects there."""
        pts = np.asarray(arena_mm, dtype=np.float64).reshape(-1, 2)
        pose = self.pose
        if pose is not None and self.camera_matrix is not None:
            world = np.column_stack([pts, np.full(len(pts), height_mm)])
            rvec, _ = cv2.Rodrigues(pose.rotation)
            tvec = -pose.rotation @ pose.centre
            dist = np.zeros(5) if self.dist_coeffs is None else self.dist_coeffs
            frame, _ = cv2.projectPoints(world, rvec, tvec, self.camera_matrix, dist)
            return np.asarray(frame, dtype=np.float64).reshape(-1, 2)
        # The inverse of to_arena's parallax: the floor point the ray reaches.
        ground: np.ndarray = self._ground  # type: ignore[attr-defined]
        h = self.camera_height_mm
        floor = ground + (pts - ground) * h / (h - height_mm)
        ideal = self.to_image(floor)
        if self.camera_matrix is None or self.dist_coeffs is None:
            return ideal
        k = self.camera_matrix
        normalised = np.column_stack(
            [
                (ideal[:, 0] - k[0, 2]) / k[0, 0],
                (ideal[:, 1] - k[1, 2]) / k[1, 1],
                np.ones(len(ideal)),
            ]
        )
        frame, _ = cv2.projectPoints(normalised, np.zeros(3), np.zeros(3), k, self.dist_coeffs)
        return np.asarray(frame, dtype=np.float64).reshape(-1, 2)

    def to_image(self, arena_mm: np.ndarray) -> np.ndarray:
        """Image pixels (undistorted) of floor points; for drawing over the video."""
        pts = np.asarray(arena_mm, dtype=np.float64).reshape(-1, 1, 2)
        inv = np.linalg.inv(self.homography)
        return np.asarray(cv2.perspectiveTransform(pts, inv)).reshape(-1, 2)

    # -- files

    def to_json(self) -> dict[str, Any]:
        def listed(a: np.ndarray | None) -> Any:
            return None if a is None else np.asarray(a).tolist()

        return {
            "format": FORMAT,
            "version": VERSION,
            "image_size": list(self.image_size),
            "homography": listed(self.homography),
            "camera_height_mm": self.camera_height_mm,
            "rms_mm": self.rms_mm,
            "camera_matrix": listed(self.camera_matrix),
            "dist_coeffs": listed(self.dist_coeffs),
            "camera_xy_mm": None if self.camera_xy_mm is None else list(self.camera_xy_mm),
            **({} if self.lens is None else {"intrinsics": self.lens.report()}),
            "rotation": listed(self.rotation),
            "tilt_deg": self.tilt_deg,
            "check_mm": self.check_mm,
            "notes": list(self.notes),
        }

    def save(self, path: Path) -> None:
        write_atomic(path, (json.dumps(self.to_json(), indent=1) + "\n").encode())

    @classmethod
    def load(cls, path: Path) -> ArenaCalibration:
        data = read_document(path)
        try:
            return cls.from_json(data)
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {exc}") from None

    @classmethod
    def from_json(cls, data: Any) -> ArenaCalibration:
        check_format(data)
        if data.get("homography") is None and data.get("camera_matrix") is not None:
            raise CalibrationError(
                "holds the camera's intrinsics but not the arena's floor yet: run "
                "`wart camera calibrate --world W --source S --out FILE` (it keeps the "
                "intrinsics), or start the camera with --auto-calibrate"
            )
        lens = lens_of(data)
        size = data.get("image_size")
        if not (
            isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) for v in size)
        ):
            raise CalibrationError("image_size: must be [width, height] in whole pixels")
        height = data.get("camera_height_mm")
        if not isinstance(height, int | float) or isinstance(height, bool):
            raise CalibrationError("camera_height_mm: must be a number")
        rms = data.get("rms_mm", 0.0)
        if not isinstance(rms, int | float) or not math.isfinite(rms):
            raise CalibrationError("rms_mm: must be a number")
        homography = matrix(data, "homography", (3, 3))
        assert homography is not None
        xy = data.get("camera_xy_mm")
        if xy is not None and not (
            isinstance(xy, list) and len(xy) == 2 and all(isinstance(v, int | float) for v in xy)
        ):
            raise CalibrationError("camera_xy_mm: must be [x, y] in mm, or null")
        return cls(
            image_size=(size[0], size[1]),
            homography=homography,
            camera_height_mm=float(height),
            rms_mm=float(rms),
            camera_matrix=matrix(data, "camera_matrix", (3, 3), optional=True),
            dist_coeffs=matrix(data, "dist_coeffs", (5,), optional=True),
            camera_xy_mm=None if xy is None else (float(xy[0]), float(xy[1])),
            lens=lens,
            rotation=matrix(data, "rotation", (3, 3), optional=True),
            tilt_deg=number(data, "tilt_deg"),
            check_mm=number(data, "check_mm"),
            notes=notes_of(data),
        )

    def warnings(self) -> list[str]:
        """What a lab should know before it grades from these poses."""
        said = list(self.notes)
        if self.check_mm is not None and self.check_mm > CHECK_WARN_MM:
            said.append(
                f"the calibration is {self.check_mm:.1f} mm off on reference markers it was not "
                f"fitted to (more than {CHECK_WARN_MM:g} mm): poses near the arena's edges will "
                "be off by about as much"
            )
        if self.pose is None:
            tilt = "" if self.tilt_deg is None else f" (about {self.tilt_deg:.0f} deg here)"
            said.append(
                "no lens intrinsics: the error grows with the camera's tilt"
                f"{tilt} and its lens's distortion, which are corrected only approximately; "
                "calibrate the lens with `wart camera calibrate --intrinsics`"
            )
        return said

    def report(self) -> str:
        """The camera as the calibration sees it, in one line for the log."""
        where = ""
        if self.camera_xy_mm is not None:
            x, y = self.camera_xy_mm
            where = f" over ({x:.0f}, {y:.0f}) mm"
        tilt = "" if self.tilt_deg is None else f", tilted {self.tilt_deg:.1f} deg"
        how = (
            "solved from the reference markers with the lens's intrinsics"
            if self.pose is not None
            else "estimated from the floor's homography and the height given (no intrinsics)"
        )
        check = (
            ""
            if self.check_mm is None
            else f"; {self.check_mm:.1f} mm rms predicting each reference marker from the others"
        )
        return (
            f"camera {self.camera_height_mm:.0f} mm up{where}{tilt} ({how}); "
            f"{self.rms_mm:.1f} mm rms on the markers fitted{check}"
        )


@functools.cache
def detector(threshold_window_px: int = 3) -> cv2.aruco.ArucoDetector:
    """The lab's marker detector (one per process and smallest thresholding window
    ``threshold_window_px``: it holds no frame's state).

    Corners are refined along the marker's contour: a 40 mm marker is about 17 px at
    640x480 over a 1 m arena, and this refinement took the heading's error from 0.9
    to 0.25 degrees (p50) there against sub-pixel corner search. It draws every
    corner about 0.8 px inward (measured on tests/kit/overhead_camera.py), which
    cancels in a marker's centre; the floor's fit over 16 reference corners follows
    their centres too (sub-pixel search there did worse on the synthetic camera).

    The bits are read for a blurred marker too: each cell sampled at its middle only
    (a third of its margin ignored), 8 px a cell, 80 % of the correctable bits
    corrected (all of them read 16 markers of no robot in 100 synthetic frames, 80 %
    read 2, as the default does) and a looser outline. On 1280x720 frames at 18
    degrees of tilt with 1/25 s exposure this read 100 % at 200 mm/s (94 % before)
    and half the markers at 320 mm/s (none before); the tracker reads the rest
    through their blur (common/tracking/deblur.py).
    """
    params = detector_parameters()
    params.adaptiveThreshWinSizeMin = threshold_window_px  # then 10 px wider, up to 23
    return cv2.aruco.ArucoDetector(dictionary(), params)


def detector_parameters() -> cv2.aruco.DetectorParameters:
    """The parameters of the lab's detector (see ``detector``), a fresh copy."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_CONTOUR
    params.errorCorrectionRate = 0.8
    params.polygonalApproxAccuracyRate = 0.06
    params.perspectiveRemovePixelPerCell = 8
    params.perspectiveRemoveIgnoredMarginPerCell = 0.3
    params.maxErroneousBitsInBorderRate = 0.6
    return params


def detect(gray: np.ndarray) -> dict[int, np.ndarray]:
    """Every marker of the lab's dictionary in a grey frame: id -> 4x2 corners (px)."""
    return detect_all(gray)[0]


def detect_all(
    gray: np.ndarray, threshold_window_px: int = 3
) -> tuple[dict[int, np.ndarray], list[np.ndarray]]:
    """The markers read (id -> 4x2 corners, px), and the 4x2 corners (px) of the outlines
    found whose bits could not be read (a blurred marker among them); the frame thresholded
    over neighbourhoods from ``threshold_window_px`` wide."""
    corners, ids, rejected = detector(threshold_window_px).detectMarkers(gray)
    unread = [np.asarray(c, dtype=np.float64).reshape(4, 2) for c in rejected]
    if ids is None:
        return {}, unread
    found = {
        int(i): np.asarray(c, dtype=np.float64).reshape(4, 2)
        for i, c in zip(ids.ravel(), corners, strict=True)
    }
    return found, unread


def calibrate(
    frame: np.ndarray,
    layout: MarkerLayout,
    *,
    camera_height_mm: float | None = None,
    camera_matrix: np.ndarray | None = None,
    dist_coeffs: np.ndarray | None = None,
    lens: Intrinsics | None = None,
) -> ArenaCalibration:
    """The floor's homography from the reference markers visible in one frame.

    With ``camera_matrix`` the camera's pose (height and tilt included) is solved
    from the markers; without, ``camera_height_mm`` is needed and the pose estimated.
    """
    if camera_matrix is None and camera_height_mm is None:
        raise CalibrationError(
            "give the camera's height above the floor (mm), or its intrinsics to solve it"
        )
    size = (frame.shape[1], frame.shape[0])
    gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    seen = detect(gray)
    found = sorted(i for i in layout.reference if i in seen)
    if len(found) < MIN_REFERENCE_MARKERS:
        raise CalibrationError(
            f"calibration needs at least {MIN_REFERENCE_MARKERS} of the reference markers "
            f"{sorted(layout.reference)} in view; saw {found or 'none'} "
            f"(all markers seen: {sorted(seen) or 'none'}). Clear the arena's corners, "
            "light it evenly and try again."
        )
    base = ArenaCalibration(
        image_size=size,
        homography=np.eye(3),
        camera_height_mm=camera_height_mm or 1000.0,
        camera_matrix=camera_matrix,
        dist_coeffs=dist_coeffs,
    )
    image_pts = base.undistort_points(np.vstack([seen[i] for i in found]))
    arena_pts = np.vstack(
        [corners_mm(*layout.reference[i], math.pi / 2, layout.reference_marker_mm) for i in found]
    )
    cal = _fit(image_pts, arena_pts, size, camera_height_mm, camera_matrix, dist_coeffs, lens)
    # Errors are taken at the markers' centres, as robots are: the detector draws each
    # corner about 0.8 px inward, which a centre cancels and a corner does not.
    residual = _centres(cal.to_arena(image_pts)) - _centres(arena_pts)
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    notes = _height_notes(cal, camera_height_mm)  # before the leave-one-out fits
    check = None
    if len(found) > MIN_REFERENCE_MARKERS:
        misses = []
        for k in range(len(found)):  # each marker predicted by a fit to the others
            out = np.zeros(len(image_pts), bool)
            out[4 * k : 4 * k + 4] = True
            part = _fit(
                image_pts[~out],
                arena_pts[~out],
                size,
                camera_height_mm,
                camera_matrix,
                dist_coeffs,
                lens,
            )
            miss = _centres(part.to_arena(image_pts[out])) - _centres(arena_pts[out])
            misses.append(float(np.linalg.norm(miss)))
        check = float(np.sqrt(np.mean(np.square(misses))))
    else:
        notes.append(
            f"only {len(found)} reference markers seen: no check on points left out of the fit"
        )
    return dataclasses.replace(cal, rms_mm=rms, check_mm=check, notes=tuple(notes))


def _centres(corners: np.ndarray) -> np.ndarray:
    """Each marker's centre from its 4 corners (rows in fours)."""
    return np.asarray(corners).reshape(-1, 4, 2).mean(axis=1)


def _height_notes(cal: ArenaCalibration, given_mm: float | None) -> list[str]:
    """A --camera-height that disagrees with what the markers imply, in both numbers."""
    if given_mm is None:
        return []
    if cal.pose is not None:
        solved = cal.camera_height_mm
        if abs(solved - given_mm) > HEIGHT_TOLERANCE * solved:
            return [
                f"--camera-height {given_mm:.0f} mm disagrees with the {solved:.0f} mm the "
                "reference markers imply with the lens's intrinsics: the markers' figure is "
                "used (measure the camera again, or check the arena's size)"
            ]
        return []
    estimate = pose_from_homography(cal.homography, cal.image_size, given_mm)
    if estimate is None:
        return [
            f"no camera {given_mm:.0f} mm up sees the floor as this one does: is "
            "--camera-height right?"
        ]
    fov = math.degrees(2 * math.atan(cal.image_size[0] / (2 * estimate[1])))
    if not FIELD_OF_VIEW_DEG[0] <= fov <= FIELD_OF_VIEW_DEG[1]:
        return [
            f"a camera {given_mm:.0f} mm up would need a lens {fov:.0f} deg wide to see the "
            "arena at this size: is --camera-height right?"
        ]
    return []


def _fit(
    image_pts: np.ndarray,
    arena_pts: np.ndarray,
    size: tuple[int, int],
    camera_height_mm: float | None,
    camera_matrix: np.ndarray | None,
    dist_coeffs: np.ndarray | None,
    lens: Intrinsics | None,
) -> ArenaCalibration:
    """The calibration fitted to these points (ideal pixels, arena mm on the floor)."""
    homography, _ = cv2.findHomography(image_pts, arena_pts, 0)
    if homography is None:
        raise CalibrationError("the reference markers' corners do not give a homography")
    rotation, camera_xy, tilt = None, None, None
    if camera_matrix is not None:
        pose = solve_pose(arena_pts, image_pts, camera_matrix)
        if pose is None:
            raise CalibrationError("the camera's position could not be solved from the markers")
        height = float(pose.centre[2])
        rotation, tilt = pose.rotation, pose.tilt_deg
        camera_xy = (float(pose.centre[0]), float(pose.centre[1]))
    else:
        assert camera_height_mm is not None
        height = camera_height_mm
        estimate = pose_from_homography(homography, size, camera_height_mm)
        if estimate is not None:
            centre = estimate[0].centre
            camera_xy, tilt = (float(centre[0]), float(centre[1])), estimate[0].tilt_deg
    return ArenaCalibration(
        image_size=size,
        homography=homography,
        camera_height_mm=height,
        camera_matrix=camera_matrix,
        dist_coeffs=dist_coeffs,
        camera_xy_mm=camera_xy,
        lens=lens,
        rotation=rotation,
        tilt_deg=tilt,
    )


def reference_points(layout: MarkerLayout) -> Mapping[int, np.ndarray]:
    """Each reference marker's corners in arena mm (for drawing and checks)."""
    return {
        i: corners_mm(x, y, math.pi / 2, layout.reference_marker_mm)
        for i, (x, y) in layout.reference.items()
    }
