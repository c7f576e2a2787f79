"""A camera's intrinsics as a lab measures them: a ChArUco board shown to the camera.

The board is filmed or photographed at many places, distances and angles;
OpenCV finds its corners (``CharucoDetector``) and solves the pinhole model with
radial and tangential distortion (``calibrateCameraExtended``, which also gives
each parameter's standard deviation). Which views to keep follows ROS's
camera_calibration: each view is placed by the board's x and y in the frame,
its size and its skew; a view too close to one already kept (their four
numbers differ by less than 0.2 in all) is a near-duplicate; a view taken while
the board moves (its corners shifted since the last frame) or that is blurred
(low variance of the Laplacian over the board) is refused; coverage is the
spread of each number against ROS's ranges, and the views are enough when
every bar is full, or after 40 views.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

# ROS camera_calibration: the spread each of x, y, size and skew must reach.
PARAM_RANGES = (0.7, 0.7, 0.4, 0.5)
PARAM_NAMES = ("x", "y", "size", "skew")
NEAR_DUPLICATE = 0.2
ENOUGH_VIEWS = 40
MIN_VIEWS = 8
STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


class IntrinsicsError(ValueError):
    """Intrinsics that cannot be made or read; the message says what to do."""


@dataclass(frozen=True)
class BoardSpec:
    """A printed ChArUco board: squares across and down, their side and their markers' side."""

    columns: int = 9
    rows: int = 6
    square_mm: float = 50.0
    marker_mm: float = 37.0
    dictionary: str = "5X5_100"

    def __post_init__(self) -> None:
        if not (3 <= self.columns <= 40 and 3 <= self.rows <= 40):
            raise IntrinsicsError("a board has 3 to 40 squares each way")
        if not 0 < self.marker_mm < self.square_mm:
            raise IntrinsicsError("a board's markers are smaller than its squares")
        if not hasattr(cv2.aruco, f"DICT_{self.dictionary}"):
            raise IntrinsicsError(f"no ArUco dictionary {self.dictionary} (e.g. 5X5_100, 4X4_50)")

    def charuco(self) -> cv2.aruco.CharucoBoard:
        dictionary = cv2.aruco.getPredefinedDictionary(
            getattr(cv2.aruco, f"DICT_{self.dictionary}")
        )
        return cv2.aruco.CharucoBoard(
            (self.columns, self.rows), self.square_mm, self.marker_mm, dictionary
        )

    @property
    def corners(self) -> int:
        return (self.columns - 1) * (self.rows - 1)


@dataclass(frozen=True)
class Intrinsics:
    """OpenCV's pinhole model of one camera at one resolution, and how well it is known."""

    image_size: tuple[int, int]
    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    reprojection_px: float = 0.0  # rms over every corner of every view kept
    std: dict[str, float] = field(default_factory=dict)  # each parameter's standard deviation
    views: int = 0

    def report(self) -> dict[str, Any]:
        """What the calibration file keeps beside the matrix and coefficients."""
        return {
            "image_size": list(self.image_size),
            "reprojection_px": self.reprojection_px,
            "std": dict(self.std),
            "views": self.views,
        }

    @classmethod
    def from_report(
        cls, report: Any, camera_matrix: np.ndarray, dist_coeffs: np.ndarray
    ) -> Intrinsics:
        if not isinstance(report, dict):
            raise IntrinsicsError("intrinsics: must be an object")
        size = report.get("image_size")
        if not (
            isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) for v in size)
        ):
            raise IntrinsicsError("intrinsics.image_size: must be [width, height] in pixels")
        std = report.get("std", {})
        if not isinstance(std, dict) or not all(
            isinstance(v, int | float) and math.isfinite(v) for v in std.values()
        ):
            raise IntrinsicsError("intrinsics.std: must map parameter names to numbers")
        rms, views = report.get("reprojection_px", 0.0), report.get("views", 0)
        if not isinstance(rms, int | float) or not isinstance(views, int):
            raise IntrinsicsError("intrinsics: reprojection_px and views must be numbers")
        return cls((size[0], size[1]), camera_matrix, dist_coeffs, float(rms), dict(std), views)

    def summary(self) -> str:
        f = self.camera_matrix
        sd = self.std
        return (
            f"{self.views} views, reprojection {self.reprojection_px:.2f} px rms; "
            f"fx {f[0, 0]:.1f}±{sd.get('fx', 0):.1f} fy {f[1, 1]:.1f}±{sd.get('fy', 0):.1f} "
            f"cx {f[0, 2]:.1f}±{sd.get('cx', 0):.1f} cy {f[1, 2]:.1f}±{sd.get('cy', 0):.1f} px; "
            f"k1 {self.dist_coeffs[0]:+.4f}±{sd.get('k1', 0):.4f} "
            f"k2 {self.dist_coeffs[1]:+.4f}±{sd.get('k2', 0):.4f}"
        )


@dataclass(frozen=True)
class Verdict:
    """What became of one offered frame: kept, or refused and why."""

    kept: bool
    reason: str
    params: tuple[float, float, float, float] | None = None


@dataclass
class _View:
    ids: np.ndarray
    corners: np.ndarray
    params: tuple[float, float, float, float]


def _sharpness(gray: np.ndarray, corners: np.ndarray) -> float:
    """Variance of the Laplacian over the board's bounding box, over the box's own variance
    (a dim board is not a blurred one) and times the corners' spacing in pixels (a near
    board has fewer edges a pixel than a far one): about 20 when sharp, 5 at 1 px of blur."""
    x, y, w, h = cv2.boundingRect(corners.astype(np.float32).reshape(-1, 1, 2))
    patch = gray[max(y, 0) : y + h, max(x, 0) : x + w]
    if patch.size < 16:
        return 0.0
    spacing = math.sqrt(w * h / len(corners))
    return float(cv2.Laplacian(patch, cv2.CV_64F).var()) / (float(patch.var()) + 1.0) * spacing


class IntrinsicsCollector:
    """Frames in, views kept or refused, coverage out; then OpenCV's calibration."""

    def __init__(
        self,
        board: BoardSpec,
        *,
        min_sharpness: float = 2.5,
        max_motion_px: float = 2.0,
        min_corner_share: float = 0.5,
    ) -> None:
        self.board = board
        self._charuco = board.charuco()
        self._detector = cv2.aruco.CharucoDetector(self._charuco)
        self._object = np.asarray(self._charuco.getChessboardCorners(), dtype=np.float32)
        self.min_sharpness = min_sharpness
        self.max_motion_px = max_motion_px
        self.min_corner_share = min_corner_share
        self.views: list[_View] = []
        self.refused: Counter[str] = Counter()
        self.image_size: tuple[int, int] | None = None
        self._last: dict[int, np.ndarray] | None = None

    # -- views

    def offer(self, frame: np.ndarray, *, consecutive: bool = True) -> Verdict:
        """One frame: kept as a view, or refused. ``consecutive``: the frame follows the
        last one offered in a video (so a moving board can be told)."""
        gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        size = (gray.shape[1], gray.shape[0])
        if self.image_size is None:
            self.image_size = size
        elif size != self.image_size:
            return self._refuse(
                f"{size[0]}x{size[1]}, not {self.image_size[0]}x{self.image_size[1]}"
            )
        corners, ids, _, _ = self._detector.detectBoard(gray)
        last, self._last = self._last, None
        if ids is None or len(ids) < max(6, self.min_corner_share * self.board.corners):
            return self._refuse("board not seen (or less than half of it)")
        ids = ids.ravel().astype(int)
        corners = corners.reshape(-1, 2).astype(np.float64)
        seen = dict(zip(ids.tolist(), corners, strict=True))
        self._last = seen
        if consecutive and last is not None:
            common = [i for i in seen if i in last]
            if common:
                motion = float(np.mean([np.linalg.norm(seen[i] - last[i]) for i in common]))
                if motion > self.max_motion_px:
                    return self._refuse("board moving")
        if _sharpness(gray, corners) < self.min_sharpness:
            return self._refuse("blurred")
        params = self._params(ids, corners, size)
        if params is None:
            return self._refuse("board seen edge-on")
        if (
            self.views
            and min(
                sum(abs(a - b) for a, b in zip(params, v.params, strict=True)) for v in self.views
            )
            <= NEAR_DUPLICATE
        ):
            return self._refuse("near-duplicate of a view kept")
        self.views.append(_View(ids, corners, params))
        return Verdict(True, "kept", params)

    def _refuse(self, reason: str) -> Verdict:
        self.refused[reason] += 1
        return Verdict(False, reason)

    def _params(
        self, ids: np.ndarray, corners: np.ndarray, size: tuple[int, int]
    ) -> tuple[float, float, float, float] | None:
        """ROS's x, y, size and skew of a view, from the board's outer corners (mapped by
        the homography of the corners seen, so a partly seen board has them too)."""
        board_xy = self._object[ids, :2].astype(np.float64)
        homography, _ = cv2.findHomography(board_xy, corners, 0)
        if homography is None:
            return None
        grid = self._object[:, :2].astype(np.float64)
        lo, hi = grid.min(axis=0), grid.max(axis=0)
        outer = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
        quad = cv2.perspectiveTransform(outer.reshape(-1, 1, 2), homography).reshape(4, 2)
        d1, d2 = quad[2] - quad[0], quad[3] - quad[1]
        area = 0.5 * abs(float(d1[0] * d2[1] - d1[1] * d2[0]))
        if area <= 1.0:
            return None
        a, b = quad[1] - quad[0], quad[1] - quad[2]
        angle = math.acos(float(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1)))
        skew = min(1.0, 2.0 * abs(math.pi / 2 - angle))
        border = math.sqrt(area)
        width, height = size
        px = min(1.0, max(0.0, (float(corners[:, 0].mean()) - border / 2) / (width - border)))
        py = min(1.0, max(0.0, (float(corners[:, 1].mean()) - border / 2) / (height - border)))
        return (px, py, math.sqrt(area / (width * height)), skew)

    # -- coverage

    def coverage(self) -> dict[str, float]:
        """Each bar from 0 to 1: the spread of the views' x, y, size and skew (ROS's
        rule: small boards and small skews are not rewarded, so those start at 0)."""
        if not self.views:
            return dict.fromkeys(PARAM_NAMES, 0.0)
        params = np.array([v.params for v in self.views])
        lo = params.min(axis=0)
        lo[2:] = 0.0
        hi = params.max(axis=0)
        spread = np.minimum((hi - lo) / np.array(PARAM_RANGES), 1.0)
        return {name: float(v) for name, v in zip(PARAM_NAMES, spread, strict=True)}

    @property
    def enough(self) -> bool:
        return len(self.views) >= ENOUGH_VIEWS or (
            len(self.views) >= MIN_VIEWS and all(v >= 1.0 for v in self.coverage().values())
        )

    def progress(self) -> str:
        """One line: the four bars, as ROS's calibrator shows them."""
        bars = " ".join(
            f"{name} [{'#' * round(10 * v)}{'.' * (10 - round(10 * v))}]"
            for name, v in self.coverage().items()
        )
        return f"{bars} {len(self.views)} views" + (" - enough" if self.enough else "")

    # -- the solve

    def calibrate(self) -> Intrinsics:
        """OpenCV's solution over the views kept (views whose error is over 3 times the
        median are dropped and it is solved again)."""
        if len(self.views) < MIN_VIEWS or self.image_size is None:
            raise IntrinsicsError(
                f"{len(self.views)} views kept; at least {MIN_VIEWS} are needed: show the board "
                "at more places, distances and angles"
            )
        views = list(self.views)
        for _ in range(2):
            result = self._solve(views)
            errors = result[-1].ravel()
            keep = errors <= max(3.0 * float(np.median(errors)), 0.5)
            if keep.all() or keep.sum() < MIN_VIEWS:
                break
            views = [v for v, k in zip(views, keep, strict=True) if k]
        rms, matrix, dist, std = result[0], result[1], result[2], result[3].ravel()
        return Intrinsics(
            image_size=self.image_size,
            camera_matrix=np.asarray(matrix, dtype=np.float64),
            dist_coeffs=np.asarray(dist, dtype=np.float64).ravel()[:5],
            reprojection_px=float(rms),
            std={n: float(s) for n, s in zip(STD_NAMES, std, strict=False)},
            views=len(views),
        )

    def _solve(self, views: list[_View]) -> tuple[Any, ...]:
        objects = [self._object[v.ids].reshape(-1, 1, 3).astype(np.float32) for v in views]
        images = [v.corners.reshape(-1, 1, 2).astype(np.float32) for v in views]
        assert self.image_size is not None
        rms, matrix, dist, _, _, std, _, per_view = cv2.calibrateCameraExtended(
            objects,
            images,
            self.image_size,
            np.eye(3),
            np.zeros(5),
            flags=cv2.CALIB_FIX_K3,
        )
        return rms, matrix, dist, std, per_view
