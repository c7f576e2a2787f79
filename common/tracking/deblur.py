"""Finding a fast robot's marker through its motion blur, where the last fixes say it went.

At a Khepera's top speed (about 320 mm/s) and a 1/25 s exposure a 40 mm marker
seen from 1.66 m is smeared over about 7 px, twice its bits' width: the
detector finds its outline but cannot read its id. The tracker knows where the
robot was and how fast it went, so it knows where to look and along which line
the picture is smeared: a small window there (and around each outline the
detector found but could not read, within the robot's reach) is deconvolved
(Wiener, a line blur of a few lengths, as the exposure is not known, along the
way the window looks smeared) and read again; only the robot's own id counts.
Measured on tests/kit/overhead_camera.py frames (18 degrees of tilt, JPEG,
noise), the window placed at the true position: at 320 mm/s the detector alone
read 28 of 60 markers, with this 60 of 60; at 400 mm/s 2 and 60 (about 7 ms a
lost robot). docs/BENCHMARKS.md has the tracker's figures, which predict.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Collection, Sequence

import cv2
import numpy as np

from common.tracking.calibration import detector_parameters
from common.tracking.markers import dictionary

WINDOW_PX = 64  # the window deconvolved: a 40 mm marker is about 25 px at 1.66 m
# Around an outline the detector found but could not read: its centre may lie 20 px off
# the marker's (the outline of a marker and the robot's dark side together, seen tilted).
OUTLINE_WINDOW_PX = 96
# The smear's length is not known (the exposure is not): the usual 5 to 7 px first, in
# half-pixel steps (a deconvolution a pixel off the true length often does not read:
# at 25 degrees of tilt, 320 mm/s, 5, 7, 9 and 11 px read 27 of 34 markers, these 33).
BLUR_LENGTHS_PX = (6.0, 5.0, 7.0, 5.5, 6.5, 4.0, 4.5, 7.5, 8.0, 9.0, 11.0)
# Around where a fast robot was, when the way its fixes predicted is wrong (it turned):
# the robot is within this window for about half a second; read at the smear lengths
# near the one that read it last (a wide window costs four narrow ones a length), along
# four axes too: a wide window's own smear is the floor's and walls', not the robot's.
WIDE_WINDOW_PX = 160
AXES = (0.0, math.pi / 4, math.pi / 2, 3 * math.pi / 4)
NOISE_TO_SIGNAL = 0.02
# Outlines shorter than this part of the marker's side are not looked at: a deblurred
# window rings, and its every small contour read as a marker cost ten times the rest
# (161 such candidates in a 96 px window: 4.6 ms a reading, 0.4 without them).
MIN_SIDE_PART = 0.5


@functools.cache
def window_detector(min_perimeter_rate: float) -> cv2.aruco.ArucoDetector:
    """The lab's detector for a doubled window, its outlines at least this part of the
    window's size round (the rate rounded by the caller: a few detectors a process)."""
    params = detector_parameters()
    params.minMarkerPerimeterRate = min_perimeter_rate
    return cv2.aruco.ArucoDetector(dictionary(), params)


def line_blur(length_px: float, angle: float, size: int = 15) -> np.ndarray:
    """The blur of a straight motion: a line ``length_px`` long at ``angle``, summing to 1."""
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    for t in np.linspace(-length_px / 2, length_px / 2, max(2, int(length_px * 4))):
        x, y = c + t * math.cos(angle), c + t * math.sin(angle)
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                          (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
            if 0 <= x0 + dx < size and 0 <= y0 + dy < size:
                kernel[y0 + dy, x0 + dx] += w
    return kernel / kernel.sum()


def wiener(image: np.ndarray, kernel: np.ndarray, nsr: float = NOISE_TO_SIGNAL) -> np.ndarray:
    """``image`` deconvolved by ``kernel`` (centred), regularised by the noise-to-signal."""
    return _wiener(np.fft.fft2(image), _spectrum(kernel, image.shape), nsr)


def _spectrum(kernel: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The kernel's spectrum over an image of ``shape``, the kernel centred at the origin."""
    padded = np.zeros(shape[:2], np.float32)
    k = kernel.shape[0]
    padded[:k, :k] = kernel
    padded = np.roll(padded, (-(k // 2), -(k // 2)), (0, 1))
    return np.fft.fft2(padded)


@functools.lru_cache(maxsize=4096)
def _line_spectrum(length_px: float, angle_deg: int, size: int) -> np.ndarray:
    """A line blur's spectrum over a ``size`` square window, its angle to the degree (a
    7 px line a degree off moves its ends by 0.06 px): windows of one robot's way reuse it."""
    return _spectrum(line_blur(length_px, math.radians(angle_deg)), (size, size))


def _wiener(image_spectrum: np.ndarray, spectrum: np.ndarray, nsr: float) -> np.ndarray:
    restored = np.fft.ifft2(image_spectrum * np.conj(spectrum) / (np.abs(spectrum) ** 2 + nsr))
    return np.asarray(np.real(restored))


def smear_angle(window: np.ndarray) -> float:
    """The direction a window is smeared along (image radians): the one its gradients
    are weakest across, from the structure tensor (a robot that turned or bounced off a
    wall since its last fix is smeared along its new way, not the predicted one)."""
    gx = cv2.Sobel(window, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(window, cv2.CV_32F, 0, 1, ksize=3)
    xx, yy, xy = float((gx * gx).sum()), float((gy * gy).sum()), float((gx * gy).sum())
    strongest = 0.5 * math.atan2(2.0 * xy, xx - yy)
    return strongest + math.pi / 2.0


def find_blurred(
    gray: np.ndarray,
    markers: Collection[int],
    at_px: np.ndarray,
    motion_angle: float | None,
    side_px: float,
    window_px: int = WINDOW_PX,
    lengths: Sequence[float] = BLUR_LENGTHS_PX,
    other_angles: Sequence[float] = (),
) -> tuple[int, np.ndarray, float] | None:
    """One of ``markers`` (about ``side_px`` a side in the frame), its 4 corners (frame px)
    and the smear's length that read it, in the window around ``at_px`` once deblurred
    along ``motion_angle`` (image radians; None: unknown) or along the way the window
    itself looks smeared, then along ``other_angles``; None if none is read there."""
    # At twice the size, an outline of MIN_SIDE_PART of the side, as a part of the window.
    rate = 4 * 2 * MIN_SIDE_PART * side_px / (2 * window_px)
    detector = window_detector(round(min(max(rate, 0.03), 1.0), 2))
    half = window_px // 2
    h, w = gray.shape
    # A window that would cross the frame's edge is moved inside it.
    x0 = min(max(round(float(at_px[0])) - half, 0), w - window_px)
    y0 = min(max(round(float(at_px[1])) - half, 0), h - window_px)
    if x0 < 0 or y0 < 0:
        return None
    window = gray[y0 : y0 + window_px, x0 : x0 + window_px].astype(np.float32)
    angles = [smear_angle(window)]
    if motion_angle is not None and abs(math.sin(motion_angle - angles[0])) > 0.25:
        angles.append(motion_angle)
    for angle in [*angles, *other_angles]:
        read = _read(window, detector, markers, angle, lengths)
        if read is not None:
            return read[0], read[1] + np.array([x0, y0]), read[2]
    return None


def _read(
    window: np.ndarray,
    detector: cv2.aruco.ArucoDetector,
    markers: Collection[int],
    angle: float,
    lengths: Sequence[float],
) -> tuple[int, np.ndarray, float] | None:
    # The window's spectrum once for every length; the line's cached by length and angle.
    image_spectrum = np.fft.fft2(window)
    degrees = round(math.degrees(angle)) % 180  # a line blur is the same turned half round
    for length in lengths:
        spectrum = _line_spectrum(length, degrees, window.shape[0])
        restored = _wiener(image_spectrum, spectrum, NOISE_TO_SIGNAL)
        sharp = np.clip(restored, 0, 255).astype(np.uint8)
        # Read at twice the size: the bits are then over 6 px wide.
        big = cv2.resize(sharp, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
        try:
            corners, ids, _ = detector.detectMarkers(big)
        except cv2.error:  # the contour refinement gives up on some restored outlines
            continue
        if ids is None:
            continue
        for found, i in zip(corners, ids.ravel(), strict=True):
            if int(i) in markers:
                # A pixel centre X of the doubled window is (X + 0.5) / 2 - 0.5 of the window.
                corners = np.asarray(found, dtype=np.float64).reshape(4, 2) / 2.0 - 0.25
                return int(i), corners, length
    return None
