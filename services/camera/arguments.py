"""Arguments shared by ``wart camera`` and ``wart camera calibrate``."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from common.tracking.markers import MarkerError, parse_grid

SOURCE_HELP = (
    "what to capture: a V4L2 device (/dev/video0, or its index 0), a video file, a network "
    "stream (rtsp://..., http://...), or synthetic:FILE (a camera rendered from the Khepera "
    "emulator's truth file, for labs without hardware)"
)

# An overhead camera over a lab's arena: from a low ceiling to a hall's.
MIN_HEIGHT_MM, MAX_HEIGHT_MM = 300.0, 10_000.0
DEFAULT_HEIGHT_MM = 1500.0


def source_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, help="the world whose arena the camera sees")
    p.add_argument("--source", required=True, help=SOURCE_HELP)
    p.add_argument(
        "--camera-height",
        type=positive(
            float, MIN_HEIGHT_MM, MAX_HEIGHT_MM, "the camera's height above the floor, mm"
        ),
        metavar="MM",
        help=f"the camera's height above the floor, {MIN_HEIGHT_MM:g} to {MAX_HEIGHT_MM:g} mm "
        f"(without the lens's intrinsics it is needed: {DEFAULT_HEIGHT_MM:g} if not given; with "
        "them it is solved from the markers, and checked against this)",
    )
    p.add_argument(
        "--reference-grid",
        type=grid,
        default=(2, 2),
        metavar="CxR",
        help="the reference markers on the floor: C columns by R rows evenly from corner to "
        "corner, the corners 45 mm in (default 2x2, the four corners; one camera over each "
        "half of a long arena: 3x2, two markers on the seam too, so each camera sees four; "
        "the camera logs where each id lies)",
    )
    p.add_argument(
        "--synthetic-over",
        type=rectangle,
        metavar="X0,Y0,X1,Y1",
        help="with synthetic:FILE, the part of the arena (mm) this camera hangs over and "
        "sees (default: the whole arena); several such cameras share one arena",
    )


def grid(text: str) -> tuple[int, int]:
    try:
        return parse_grid(text)
    except MarkerError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def rectangle(text: str) -> tuple[float, float, float, float]:
    """An argparse type: X0,Y0,X1,Y1 in mm, a rectangle at least 100 mm each way."""
    try:
        x0, y0, x1, y1 = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"a rectangle of the arena is X0,Y0,X1,Y1 in mm, e.g. 0,0,1100,1000; got {text!r}"
        ) from None
    values = (x0, y0, x1, y1)
    if not all(math.isfinite(v) and abs(v) <= 1e6 for v in values):
        raise argparse.ArgumentTypeError(f"the rectangle's corners must be finite mm; got {text}")
    if x1 - x0 < 100 or y1 - y0 < 100:
        raise argparse.ArgumentTypeError(
            f"the rectangle must be at least 100 mm each way, X1 > X0 and Y1 > Y0; got {text}"
        )
    return x0, y0, x1, y1


def positive(
    kind: Callable[[str], float], low: float, high: float, what: str = ""
) -> Callable[[str], float]:
    """An argparse type: a number of ``kind`` from ``low`` to ``high``, said in words if not."""
    said = f"{what}: " if what else ""

    def check(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{said}not a number: {text!r}") from None
        if not (math.isfinite(value) and low <= value <= high):
            raise argparse.ArgumentTypeError(f"{said}must be {low:g} to {high:g}; got {text}")
        return value

    return check
