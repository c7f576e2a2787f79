"""The camera's pose over the floor, and rays from pixels to planes above it.

With the camera's intrinsics the pose comes from the reference markers by
``cv2.solvePnP``; a marker ``h`` mm up is where its own (undistorted) ray meets
the plane ``z = h``. Without intrinsics the floor's homography and the camera's
height (measured by the lab) still imply a pose, if the pixels are square, the
principal point is the image's centre and the lens does not distort: good
enough to say how far the camera is tilted and to correct parallax toward the
floor point really under the camera, not the point under the image's centre.

Arena axes: x right, y up (seen from above), z up from the floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraPose:
    """``rotation``: arena -> camera axes (rows are the camera's x, y, z in the arena);
    ``centre``: the camera's optical centre in arena mm (z its height)."""

    rotation: np.ndarray
    centre: np.ndarray

    @property
    def tilt_deg(self) -> float:
        """The optical axis' angle from straight down."""
        axis = self.rotation[2]
        return math.degrees(math.acos(min(1.0, abs(float(axis[2])))))

    def rays(self, camera_matrix: np.ndarray, pixels: np.ndarray) -> np.ndarray:
        """Arena directions of the rays through ideal (undistorted) pixels."""
        pts = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        homogeneous = np.column_stack([pts, np.ones(len(pts))])
        cam = np.linalg.solve(camera_matrix, homogeneous.T).T
        return np.asarray(cam @ self.rotation)

    def to_plane(self, camera_matrix: np.ndarray, pixels: np.ndarray, z_mm: float) -> np.ndarray:
        """Arena (x, y) mm where each pixel's ray meets the plane ``z = z_mm``."""
        rays = self.rays(camera_matrix, pixels)
        t = (z_mm - self.centre[2]) / rays[:, 2]
        return np.asarray(self.centre[:2] + t[:, None] * rays[:, :2])


def solve_pose(
    floor_mm: np.ndarray, pixels: np.ndarray, camera_matrix: np.ndarray
) -> CameraPose | None:
    """The camera's pose from floor points (arena mm) and their ideal pixels."""
    objects = np.column_stack([floor_mm, np.zeros(len(floor_mm))]).astype(np.float64)
    ok, rvec, tvec = cv2.solvePnP(
        objects, np.asarray(pixels, dtype=np.float64), camera_matrix, None
    )
    if not ok:
        return None
    rotation, _ = cv2.Rodrigues(rvec)
    centre = (-rotation.T @ tvec).ravel()
    if centre[2] < 0:  # the mirror solution, below the floor
        return None
    return CameraPose(np.asarray(rotation), centre)


def pose_from_homography(
    homography: np.ndarray, image_size: tuple[int, int], camera_height_mm: float
) -> tuple[CameraPose, float] | None:
    """The pose and focal length (px) a floor homography (image px -> arena mm) implies for
    a camera ``camera_height_mm`` above the floor with square pixels, its principal point
    at the image's centre and no distortion. The height fixes the focal length (a longer
    lens sees the same floor from further up); the homography then gives the rotation.
    None when no focal length from 0.2 to 20 frame widths fits."""
    w = max(image_size)
    lo, hi = math.log(0.2 * w), math.log(20.0 * w)
    low, high = _pose_for_focal(homography, image_size, math.exp(lo)), None
    if low is None:
        return None
    for _ in range(60):  # bisection: the implied height grows with the focal length
        mid = (lo + hi) / 2.0
        pose = _pose_for_focal(homography, image_size, math.exp(mid))
        if pose is None:
            return None
        if pose.centre[2] < camera_height_mm:
            lo = mid
        else:
            hi, high = mid, pose
    if high is None or abs(high.centre[2] - camera_height_mm) > 0.01 * camera_height_mm:
        return None
    return high, math.exp(hi)


def _pose_for_focal(
    homography: np.ndarray, image_size: tuple[int, int], focal: float
) -> CameraPose | None:
    w, h = image_size
    k = np.array([[focal, 0.0, w / 2.0], [0.0, focal, h / 2.0], [0.0, 0.0, 1.0]])
    m = np.linalg.solve(k, np.linalg.inv(homography))
    m = m * 2.0 / (np.linalg.norm(m[:, 0]) + np.linalg.norm(m[:, 1]))
    if m[2, 2] < 0:  # the floor in front of the camera
        m = -m
    r1, r2 = m[:, 0], m[:, 1]
    # The nearest rotation to [r1 r2 r1xr2] (they are only nearly orthonormal).
    u, _, vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        return None
    centre = -rotation.T @ m[:, 2]
    return CameraPose(rotation, centre)
