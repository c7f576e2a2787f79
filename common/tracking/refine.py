"""A marker's corners refined by aligning its whole known pattern with the frame.

The detector places a marker's corners from its outline alone: four lines fitted
to the thresholded contour's pixels, each a few pixels long on a 40 mm marker
(about 21 px at 1.8 m through a 1280x720 lens), so noise, JPEG and the pixel
grid's aliasing move them by a few tenths of a pixel, and the heading taken
from them by up to a degree (0.94 deg at p99 on standing robots at 10 degrees
of tilt). The marker's pattern is known to the last bit: aligning it with the
frame (OpenCV's ECC, an affine warp over the marker and its white margin) uses
every edge it has, its border's and each bit's, and every pixel along them,
and puts the same corners within a few hundredths of a pixel (0.19 deg at p99
there). Over a marker of 20 to 40 px the perspective and the lens's distortion
are far below a pixel: an affine warp fits it.

The alignment starts from the detector's corners and is refused (those corners
kept) when it does not converge or moves a corner further than the detector
can be off: it refines, it never relocates.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from common.tracking.markers import marker_image

PX_PER_CELL = 4  # the pattern's resolution (finer cost more and gave the same corners)
MARGIN_CELLS = 1  # the white margin around the marker that is aligned too (its border's edge)
MAX_SHIFT_PX = 1.5  # a corner moved further: not the same marker's alignment, refused
_CELLS = 6  # a 4x4 marker and its black border
_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-4)
_PATCH_PAD_PX = 6  # the frame cut around the marker: its margin and some room to move


@functools.cache
def _pattern(marker: int) -> np.ndarray:
    """The marker with its white margin, PX_PER_CELL a cell, as float32."""
    pad = MARGIN_CELLS * PX_PER_CELL
    image = marker_image(marker, _CELLS * PX_PER_CELL)
    framed = cv2.copyMakeBorder(image, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    return np.asarray(framed, dtype=np.float32)


@functools.cache
def _start_solver() -> np.ndarray:
    """The least-squares solver (pseudo-inverse) of the affine warp taking the pattern's
    corners to four found ones: the pattern's corners never change, so it is worked out once."""
    return np.linalg.pinv(np.c_[_pattern_corners(), np.ones(4)])


def _pattern_corners() -> np.ndarray:
    """The marker's corners in the pattern's pixels (OpenCV's order: from its top left,
    clockwise; pixel centres at integers, so an edge lies half a pixel before the first)."""
    lo = MARGIN_CELLS * PX_PER_CELL - 0.5
    hi = lo + _CELLS * PX_PER_CELL
    return np.array([[lo, lo], [hi, lo], [hi, hi], [lo, hi]])


def refine_corners(gray: np.ndarray, marker: int, corners: np.ndarray) -> np.ndarray:
    """``corners`` (4x2 px, as the detector gives them) of ``marker`` in the grey frame
    ``gray``, refined by aligning the marker's pattern; the given corners if it fails."""
    corners = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    h, w = gray.shape[:2]
    x0, y0 = np.floor(corners.min(axis=0) - _PATCH_PAD_PX).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0) + _PATCH_PAD_PX).astype(int) + 1
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
        return corners  # at the frame's edge: its margin is not all in view
    patch = np.asarray(gray[y0:y1, x0:x1], dtype=np.float32)
    origin = np.array([x0, y0], dtype=np.float64)
    ideal = _pattern_corners()
    # The affine warp (pattern -> patch) that best takes the ideal corners to the found.
    start = _start_solver() @ (corners - origin)
    warp = np.ascontiguousarray(start.T, dtype=np.float32)
    try:
        # Both images smoothed by a 3 px Gaussian first (OpenCV's stubs type that argument
        # for UMat only; arrays take it too).
        _, warp = cv2.findTransformECC(  # type: ignore[call-overload]
            _pattern(marker), patch, warp, cv2.MOTION_AFFINE, _CRITERIA, None, 3
        )
    except cv2.error:  # it did not converge (a marker half covered, say)
        return corners
    refined = ideal @ warp[:, :2].T.astype(np.float64) + warp[:, 2] + origin
    if not np.all(np.isfinite(refined)):
        return corners
    if np.max(np.linalg.norm(refined - corners, axis=1)) > MAX_SHIFT_PX:
        return corners
    return refined
