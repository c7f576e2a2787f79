"""A camera over an arena that does not exist: frames rendered from known poses.

For tests, benchmarks and labs without hardware. A pinhole camera hangs above
the arena (straight down by default, optionally tilted) and sees the floor,
its walls, the reference markers and each robot: a dark disc with its marker on
top, at the marker's height, so the frames carry the parallax a real camera
sees. Blur, sensor noise and barrel distortion are optional and seeded.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from common.tracking.markers import MarkerLayout, corners_mm, marker_image

Pose = tuple[float, float, float]

FLOOR_GREY = 205
WALL_GREY = 70
ROBOT_GREY = 55
TEXTURE_PX_PER_MM = 1.0
QUIET_CELLS = 1  # white cells around a marker (its quiet zone), each side


@dataclass(frozen=True)
class CameraModel:
    """Where the camera hangs and what it sees (mm, degrees, pixels)."""

    width: int = 640
    height: int = 480
    height_mm: float = 1500.0
    # Where it hangs over the floor; None: above the arena's centre.
    x_mm: float | None = None
    y_mm: float | None = None
    tilt_deg: float = 0.0  # about the image's horizontal axis
    margin: float = 1.12  # field of view over the arena's extent
    k1: float = 0.0  # radial distortion (negative: barrel)
    k2: float = 0.0


class SyntheticCamera:
    """Renders an arena of ``width_mm`` x ``height_mm`` from robots' true poses."""

    def __init__(
        self,
        width_mm: float,
        height_mm: float,
        layout: MarkerLayout,
        model: CameraModel | None = None,
        *,
        robot_radius_mm: float = 27.5,
        wall_mm: float = 12.0,
        blur_sigma_px: float = 0.0,
        noise_sigma: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.width_mm, self.height_mm = width_mm, height_mm
        self.layout = layout
        self.model = model or CameraModel()
        self.robot_radius_mm = robot_radius_mm
        self.blur_sigma_px = blur_sigma_px
        self.noise_sigma = noise_sigma
        self._rng = np.random.default_rng(seed)
        m = self.model
        # Unplaced, a tilted camera hangs off-centre so that it aims at the centre.
        aim = m.height_mm * math.tan(math.radians(m.tilt_deg))
        cx = width_mm / 2.0 if m.x_mm is None else m.x_mm
        cy = height_mm / 2.0 + aim if m.y_mm is None else m.y_mm
        self.camera_mm = np.array([cx, cy, m.height_mm])
        # The focal length that fits the arena's larger side (with a margin) in view.
        extent = max(width_mm / m.width, height_mm / m.height) * m.margin
        f = m.height_mm / extent
        self.camera_matrix = np.array(
            [[f, 0.0, m.width / 2.0], [0.0, f, m.height / 2.0], [0.0, 0.0, 1.0]]
        )
        t = math.radians(m.tilt_deg)
        # Camera axes in the arena: x right, y down the image (arena -y), z along the view.
        look_down = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
        tilt = np.array(
            [[1.0, 0.0, 0.0], [0.0, math.cos(t), -math.sin(t)], [0.0, math.sin(t), math.cos(t)]]
        )
        self._rotation = tilt @ look_down
        self.dist_coeffs = np.array([m.k1, m.k2, 0.0, 0.0, 0.0]) if (m.k1 or m.k2) else None
        self._floor_texture = self._draw_floor(wall_mm)
        self._distort_map = self._distortion_map() if self.dist_coeffs is not None else None
        self._markers = {
            i: self._with_quiet_zone(marker_image(i, 6 * 20)) for i in layout.robots.values()
        }
        self._floor_seen: np.ndarray | None = None  # the floor as the camera sees it: fixed

    # -- projection

    def project(self, points_mm: np.ndarray, z_mm: float = 0.0) -> np.ndarray:
        """Ideal (undistorted) image pixels of arena points at height ``z_mm``."""
        pts = np.asarray(points_mm, dtype=np.float64).reshape(-1, 2)
        world = np.column_stack([pts, np.full(len(pts), z_mm)]) - self.camera_mm
        cam = world @ self._rotation.T
        uvw = cam @ self.camera_matrix.T
        return uvw[:, :2] / uvw[:, 2:3]

    def plane_homography(self, z_mm: float = 0.0) -> np.ndarray:
        """Arena mm at height ``z_mm`` -> ideal image pixels."""
        src = np.array([[0.0, 0.0], [1000.0, 0.0], [1000.0, 1000.0], [0.0, 1000.0]])
        return cv2.getPerspectiveTransform(
            src.astype(np.float32), self.project(src, z_mm).astype(np.float32)
        )

    # -- drawing

    def _draw_floor(self, wall_mm: float) -> np.ndarray:
        s = TEXTURE_PX_PER_MM
        w, h = math.ceil(self.width_mm * s), math.ceil(self.height_mm * s)
        tex = np.full((h, w), FLOOR_GREY, np.uint8)
        wall = max(1, round(wall_mm * s))
        tex[:wall, :] = tex[-wall:, :] = WALL_GREY
        tex[:, :wall] = tex[:, -wall:] = WALL_GREY
        side = self.layout.reference_marker_mm
        for marker, (x, y) in self.layout.reference.items():
            img = self._with_quiet_zone(marker_image(marker, 6 * 20))
            full = side * (6 + 2 * QUIET_CELLS) / 6.0
            quad = corners_mm(x, y, math.pi / 2, full) * s
            quad[:, 1] = h - quad[:, 1]  # texture rows grow downward (arena -y)
            self._paste(tex, img, quad)
        return tex

    @staticmethod
    def _with_quiet_zone(img: np.ndarray) -> np.ndarray:
        cell = img.shape[0] // 6
        pad = cell * QUIET_CELLS
        return cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)

    @staticmethod
    def _paste(canvas: np.ndarray, img: np.ndarray, quad_px: np.ndarray) -> None:
        """Warp ``img`` onto the quadrilateral ``quad_px`` (TL, TR, BR, BL) of ``canvas``."""
        x0 = max(math.floor(quad_px[:, 0].min()) - 1, 0)
        y0 = max(math.floor(quad_px[:, 1].min()) - 1, 0)
        x1 = min(math.ceil(quad_px[:, 0].max()) + 2, canvas.shape[1])
        y1 = min(math.ceil(quad_px[:, 1].max()) + 2, canvas.shape[0])
        if x1 <= x0 or y1 <= y0:
            return
        n = img.shape[0]
        src = np.array([[0, 0], [n, 0], [n, n], [0, n]], np.float32)
        dst = (quad_px - [x0, y0]).astype(np.float32)
        m = cv2.getPerspectiveTransform(src, dst)
        roi = canvas[y0:y1, x0:x1]
        size = (x1 - x0, y1 - y0)
        warped = cv2.warpPerspective(img, m, size, flags=cv2.INTER_AREA)
        mask = cv2.warpPerspective(np.full_like(img, 255), m, size, flags=cv2.INTER_AREA)
        alpha = mask.astype(np.float32) / 255.0
        roi[:] = (roi * (1.0 - alpha) + warped * alpha).astype(np.uint8)

    def _distortion_map(self) -> tuple[np.ndarray, np.ndarray]:
        """For each pixel of the distorted frame, where it lies in the ideal one."""
        m = self.model
        u, v = np.meshgrid(
            np.arange(m.width, dtype=np.float32), np.arange(m.height, dtype=np.float32)
        )
        grid = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        ideal = cv2.undistortPoints(
            grid, self.camera_matrix, self.dist_coeffs, P=self.camera_matrix
        )
        ideal = ideal.reshape(m.height, m.width, 2)
        return ideal[..., 0].astype(np.float32), ideal[..., 1].astype(np.float32)

    def _floor(self) -> np.ndarray:
        """The floor and its reference markers in the ideal image, warped once (a tenth of a
        frame's cost in a camera process): the camera never moves."""
        if self._floor_seen is None:
            m = self.model
            s = TEXTURE_PX_PER_MM
            tex_to_arena = np.array(
                [[1.0 / s, 0.0, 0.0], [0.0, -1.0 / s, self.height_mm], [0.0, 0.0, 1.0]]
            )
            floor = self.plane_homography(0.0) @ tex_to_arena
            self._floor_seen = cv2.warpPerspective(
                self._floor_texture,
                floor,
                (m.width, m.height),
                flags=cv2.INTER_AREA,
                borderValue=30,
            )
        return self._floor_seen

    def render(self, poses: Mapping[str, Pose], *, hidden: Sequence[str] = ()) -> np.ndarray:
        """A BGR frame of the arena with each robot of ``poses`` at its pose.

        ``hidden`` robots are drawn without their marker (an occluded marker).
        """
        gray = self._floor().copy()
        body_top = max(self.layout.robot_marker_height_mm - 1.0, 0.0)
        angles = np.linspace(0.0, 2 * math.pi, 40, endpoint=False)
        for agent, (x, y, heading) in poses.items():
            ring = np.column_stack(
                [
                    x + self.robot_radius_mm * np.cos(angles),
                    y + self.robot_radius_mm * np.sin(angles),
                ]
            )
            for z in (0.0, body_top):
                cv2.fillPoly(
                    gray,
                    [np.round(self.project(ring, z) * 16).astype(np.int32)],
                    ROBOT_GREY,
                    cv2.LINE_AA,
                    4,
                )
            marker = self.layout.robots.get(agent)
            if marker is None or agent in hidden:
                continue
            full = self.layout.robot_marker_mm * (6 + 2 * QUIET_CELLS) / 6.0
            quad = self.project(corners_mm(x, y, heading, full), self.layout.robot_marker_height_mm)
            self._paste(gray, self._markers[marker], quad)
        if self._distort_map is not None:
            gray = cv2.remap(gray, *self._distort_map, cv2.INTER_LINEAR, borderValue=30)
        if self.blur_sigma_px > 0:
            gray = cv2.GaussianBlur(gray, (0, 0), self.blur_sigma_px)
        if self.noise_sigma > 0:
            noisy = gray + self._rng.normal(0.0, self.noise_sigma, gray.shape)
            gray = np.clip(noisy, 0, 255).astype(np.uint8)
        return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
