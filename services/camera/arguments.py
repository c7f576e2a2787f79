"""Arguments shared by ``wart camera`` and ``wart camera calibrate``."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

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
