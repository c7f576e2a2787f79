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
    # Read at twice the size, a marker's cells are over 6 px wide: thresholded over 13 and 23
    # px neighbourhoods, not 3 (tracker.threshold_window_px says why).
    params.adaptiveThreshWinSizeMin = 13
    return cv2.aruco.ArucoDetector(dictionary(), params)


def line_blur(length_px: float, angle: float, size: int = 15) -> np.ndarray:
    """The blur of a straight motion: a line ``length_px`` long at ``angle``, summing to 1."""
    return _line(length_px, angle, size, size, size // 2)


def _line(length_px: float, angle: float, size: int, out: int, centre: int) -> np.ndarray:
    """A ``size`` square line blur put in an ``out`` square, its middle at pixel ``centre``
    (0: the origin, wrapped round the edges as a spectrum's kernel is)."""
    c = size // 2
    t = np.linspace(-length_px / 2, length_px / 2, max(2, int(length_px * 4)))
    x, y = c + t * math.cos(angle), c + t * math.sin(angle)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    cells, weights = [], []
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                      (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):  # fmt: skip
        xs, ys = x0 + dx, y0 + dy
        inside = (xs >= 0) & (xs < size) & (ys >= 0) & (ys < size)
        shift = centre - c
        cells.append(((ys[inside] + shift) % out) * out + (xs[inside] + shift) % out)
        weights.append(w[inside])
    kernel = np.bincount(np.concatenate(cells), np.concatenate(weights), out * out)
    return (kernel / kernel.sum()).reshape(out, out).astype(np.float32)


def wiener(image: np.ndarray, kernel: np.ndarray, nsr: float = NOISE_TO_SIGNAL) -> np.ndarray:
    """``image`` deconvolved by ``kernel`` (centred), regularised by the noise-to-signal."""
    return _restore(np.fft.rfft2(image), _filter(_spectrum(kernel, image.shape), nsr), image.shape)


def _spectrum(kernel: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The kernel's spectrum over an image of ``shape``, the kernel centred at the origin
    (the half a real image's spectrum keeps)."""
    padded = np.zeros(shape[:2], np.float32)
    k = kernel.shape[0]
    padded[:k, :k] = kernel
    padded = np.roll(padded, (-(k // 2), -(k // 2)), (0, 1))
    return np.fft.rfft2(padded)


def _filter(spectrum: np.ndarray, nsr: float) -> np.ndarray:
    """Wiener's filter for a blur of this spectrum: what the image's spectrum is multiplied by."""
    return np.asarray(np.conj(spectrum) / (np.abs(spectrum) ** 2 + nsr))


@functools.lru_cache(maxsize=1024)
def _line_filter(length_px: float, angle_deg: int, size: int) -> np.ndarray:
    """Wiener's filter for a line blur over a ``size`` square window, its angle to the degree
    (a 7 px line a degree off moves its ends by 0.06 px): windows of one robot's way reuse it."""
    kernel = _line(length_px, math.radians(angle_deg), 15, size, 0)
    return _filter(np.fft.rfft2(kernel), NOISE_TO_SIGNAL)


def _restore(
    image_spectrum: np.ndarray, wiener_filter: np.ndarray, shape: tuple[int, ...]
) -> np.ndarray:
    # Image and kernel are real: the half spectrum holds everything and comes back real.
    return np.fft.irfft2(image_spectrum * wiener_filter, s=shape[:2])


def smear_angle(window: np.ndarray) -> float:
    """The direction a window is smeared along (image radians): the one its gradients
    are weakest across, from the structure tensor (a robot that turned or bounced off a
    wall since its last fix is smeared along its new way, not the predicted one)."""
    gx = cv2.Sobel(window, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(window, cv2.CV_32F, 0, 1, ksize=3)
    xx, yy, xy = float((gx * gx).sum()), float((gy * gy).sum()), float((gx * gy).sum())
    strongest = 0.5 * math.atan2(2.0 * xy, xx - yy)
    return strongest + math.pi / 2.0


# What the deblurred windows of one frame read: (window's corner x and y, its size, the
# detector's outline rate, the smear's angle to the degree and its length) -> the markers read
# there (id, corners in the window). Robots lost near each other look at the same outlines.
Readings = dict[tuple[int, int, int, float, int, float], list[tuple[int, np.ndarray]]]


def find_blurred(
    gray: np.ndarray,
    markers: Collection[int],
    at_px: np.ndarray,
    motion_angle: float | None,
    side_px: float,
    window_px: int = WINDOW_PX,
    lengths: Sequence[float] = BLUR_LENGTHS_PX,
    other_angles: Sequence[float] = (),
    readings: Readings | None = None,
) -> tuple[int, np.ndarray, float] | None:
    """One of ``markers`` (about ``side_px`` a side in the frame), its 4 corners (frame px)
    and the smear's length that read it, in the window around ``at_px`` once deblurred
    along ``motion_angle`` (image radians; None: unknown) or along the way the window
    itself looks smeared, then along ``other_angles``; None if none is read there.
    ``readings`` (one frame's) keeps what each deblurred window read, for the next asker."""
    # At twice the size, an outline of MIN_SIDE_PART of the side, as a part of the window.
    rate = round(min(max(4 * 2 * MIN_SIDE_PART * side_px / (2 * window_px), 0.03), 1.0), 2)
    detector = window_detector(rate)
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
    spectrum: np.ndarray | None = None  # the window's, once for every angle and length
    for angle in [*angles, *other_angles]:
        degrees = round(math.degrees(angle)) % 180  # a line blur is the same turned half round
        for length in lengths:
            key = (x0, y0, window_px, rate, degrees, length)
            found = None if readings is None else readings.get(key)
            if found is None:
                if spectrum is None:
                    spectrum = np.fft.rfft2(window)
                found = _read(window, spectrum, detector, degrees, length)
                if readings is not None:
                    readings[key] = found
            for marker, corners in found:
                if marker in markers:
                    return marker, corners + np.array([x0, y0]), length
    return None


def _read(
    window: np.ndarray,
    spectrum: np.ndarray,
    detector: cv2.aruco.ArucoDetector,
    degrees: int,
    length: float,
) -> list[tuple[int, np.ndarray]]:
    """The markers read in ``window`` (its ``spectrum`` given) deblurred at this smear: ids
    and corners (window px)."""
    restored = _restore(spectrum, _line_filter(length, degrees, window.shape[0]), window.shape)
    sharp = np.clip(restored, 0, 255).astype(np.uint8)
    # Read at twice the size: the bits are then over 6 px wide.
    big = cv2.resize(sharp, None, fx=2, fy=2, interpolation=cv2.INTER_CUBIC)
    try:
        corners, ids, _ = detector.detectMarkers(big)
    except cv2.error:  # the contour refinement gives up on some restored outlines
        return []
    if ids is None:
        return []
    # A pixel centre X of the doubled window is (X + 0.5) / 2 - 0.5 of the window.
    return [
        (int(i), np.asarray(found, dtype=np.float64).reshape(4, 2) / 2.0 - 0.25)
        for found, i in zip(corners, ids.ravel(), strict=True)
    ]
