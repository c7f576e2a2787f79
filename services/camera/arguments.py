"""Arguments shared by ``wart camera`` and ``wart camera calibrate``."""

from __future__ import annotations

import argparse
from collections.abc import Callable

SOURCE_HELP = (
    "what to capture: a V4L2 device (/dev/video0, or its index 0), a video file, a network "
    "stream (rtsp://..., http://...), or synthetic:FILE (a camera rendered from the Khepera "
    "emulator's truth file, for labs without hardware)"
)


def source_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--world", required=True, help="the world whose arena the camera sees")
    p.add_argument("--source", required=True, help=SOURCE_HELP)
    p.add_argument(
        "--camera-height",
        type=float,
        default=1500.0,
        metavar="MM",
        help="the camera's height above the floor (default 1500), for a camera looking "
        "straight down without known intrinsics",
    )


def positive(kind: Callable[[str], float], low: float, high: float) -> Callable[[str], float]:
    """An argparse type: a number of ``kind`` from ``low`` to ``high``, said in words if not."""

    def check(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be {low:g} to {high:g}; got {text}")
        return value

    return check
