"""The markers of an arena: which id marks which robot, where the reference markers lie.

Robots carry one ArUco marker each on their top plate, its top edge toward the
robot's heading; reference markers lie flat on the floor at known arena
points, their top edge toward the arena's +y: four at the corners, or a grid of
them where several cameras share a big arena (one camera per half: a column
along the seam too, so each camera sees four). One dictionary for every lab
(4x4 bits, 50 ids): small markers stay readable at 640x480 over a 1 m arena.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

DICTIONARY_ID = cv2.aruco.DICT_4X4_50
MARKER_IDS = 50  # ids 0..49 exist in the dictionary
REFERENCE_IDS = (46, 47, 48, 49)  # lower-left, lower-right, upper-right, upper-left
# A grid of reference markers: the corners keep REFERENCE_IDS (printed markers stay
# valid), the others take the ids below them. At most 5x5: 25 ids left for robots.
MAX_GRID = 5


class MarkerError(ValueError):
    """A marker layout that cannot work (a duplicate id, an id outside the dictionary)."""


def dictionary() -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(DICTIONARY_ID)


def marker_image(marker_id: int, pixels: int) -> np.ndarray:
    """The marker as a grey image ``pixels`` square (black and white, no quiet zone)."""
    return cv2.aruco.generateImageMarker(dictionary(), marker_id, pixels)


@dataclass(frozen=True)
class MarkerLayout:
    """Which marker is which: robots' ids and sizes, reference markers' floor points.

    Sizes and heights in mm. ``robot_marker_height_mm`` is the marker's height above
    the floor (a Khepera's top plate): the tracker corrects the parallax it causes.
    """

    robots: Mapping[str, int]
    reference: Mapping[int, tuple[float, float]]
    robot_marker_mm: float = 40.0
    reference_marker_mm: float = 50.0
    robot_marker_height_mm: float = 40.0
    agent_of: Mapping[int, str] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        ids = list(self.robots.values()) + list(self.reference)
        bad = [i for i in ids if not 0 <= i < MARKER_IDS]
        if bad:
            raise MarkerError(f"marker ids must be 0 to {MARKER_IDS - 1}; got {sorted(bad)}")
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            raise MarkerError(f"marker ids {dup} are used twice (robots and reference markers)")
        if len(self.reference) < 4:
            raise MarkerError("a layout needs 4 reference markers on the floor")
        for name, size in (
            ("robot", self.robot_marker_mm),
            ("reference", self.reference_marker_mm),
        ):
            if not 5.0 <= size <= 500.0:
                raise MarkerError(f"{name} markers must be 5 to 500 mm wide; got {size}")
        object.__setattr__(self, "agent_of", {v: k for k, v in self.robots.items()})


def robot_markers(agents: Sequence[str], references: int = len(REFERENCE_IDS)) -> dict[str, int]:
    """The lab's convention: robot ``kN`` wears marker N (so a robot keeps its marker
    when others join or leave); other names take the lowest free ids in order. The top
    ``references`` ids are the floor's."""
    robot_ids = MARKER_IDS - references
    if len(agents) > robot_ids:
        raise MarkerError(f"at most {robot_ids} marked robots per arena; got {len(agents)}")
    ids: dict[str, int] = {}
    for agent in agents:
        if re.fullmatch(r"k\d{1,2}", agent) and int(agent[1:]) < robot_ids:
            ids[agent] = int(agent[1:])
    free = (i for i in range(robot_ids) if i not in ids.values())
    for agent in agents:
        if agent not in ids:
            ids[agent] = next(free)
    return ids


def default_layout(
    width_mm: float,
    height_mm: float,
    robots: Sequence[str] | Mapping[str, int],
    *,
    inset_mm: float = 45.0,
    grid: tuple[int, int] = (2, 2),
) -> MarkerLayout:
    """Robots' markers by :func:`robot_markers` (or as given); the references as
    :func:`reference_grid` lays them."""
    reference = reference_grid(width_mm, height_mm, grid, inset_mm=inset_mm)
    return MarkerLayout(
        robots=dict(robots)
        if isinstance(robots, Mapping)
        else robot_markers(robots, len(reference)),
        reference=reference,
    )


def reference_grid(
    width_mm: float, height_mm: float, grid: tuple[int, int] = (2, 2), *, inset_mm: float = 45.0
) -> dict[int, tuple[float, float]]:
    """``columns`` x ``rows`` reference markers evenly spaced from corner to corner, the
    corners ``inset_mm`` in (clear of a 55 mm robot pressed into them). 2x2: the four
    corners; 3x2: the corners and two markers on the seam between an arena's halves
    (one camera over each half sees four); 3x3 for four cameras, one per quarter.

    The corners wear ids 46 to 49 as ever; the other markers take 45, 44, ... row by
    row from the lower left, so a lab prints the ids :func:`grid_description` lists."""
    columns, rows = grid
    if not (2 <= columns <= MAX_GRID and 2 <= rows <= MAX_GRID):
        raise MarkerError(
            f"a grid of reference markers is 2 to {MAX_GRID} columns by 2 to {MAX_GRID} rows; "
            f"got {columns}x{rows}"
        )
    x0, y0, x1, y1 = inset_mm, inset_mm, width_mm - inset_mm, height_mm - inset_mm
    if x1 <= x0 or y1 <= y0:
        raise MarkerError(f"an arena of {width_mm:g} x {height_mm:g} mm has no room for markers")
    corner_ids = {
        (0, 0): REFERENCE_IDS[0],
        (columns - 1, 0): REFERENCE_IDS[1],
        (columns - 1, rows - 1): REFERENCE_IDS[2],
        (0, rows - 1): REFERENCE_IDS[3],
    }
    inner = iter(range(REFERENCE_IDS[0] - 1, -1, -1))
    placed: dict[int, tuple[float, float]] = {}
    for row in range(rows):
        for column in range(columns):
            marker = corner_ids.get((column, row))
            if marker is None:
                marker = next(inner)
            x = x0 + (x1 - x0) * column / (columns - 1)
            y = y0 + (y1 - y0) * row / (rows - 1)
            placed[marker] = (x, y)
    return dict(sorted(placed.items()))


def grid_description(reference: Mapping[int, tuple[float, float]]) -> str:
    """Where to lay each reference marker, in words for the log."""
    return ", ".join(f"{i} at ({x:.0f}, {y:.0f})" for i, (x, y) in sorted(reference.items()))


def parse_grid(text: str) -> tuple[int, int]:
    """``CxR`` (e.g. ``3x2``) as (columns, rows); MarkerError in words if not."""
    parts = text.lower().split("x")
    try:
        columns, rows = (int(v) for v in parts)
    except ValueError:
        raise MarkerError(
            f"a grid of reference markers is COLUMNSxROWS, e.g. 3x2; got {text!r}"
        ) from None
    if not (2 <= columns <= MAX_GRID and 2 <= rows <= MAX_GRID):
        raise MarkerError(
            f"a grid of reference markers is 2 to {MAX_GRID} columns by 2 to {MAX_GRID} rows; "
            f"got {text}"
        )
    return columns, rows


def corners_mm(cx: float, cy: float, heading: float, side: float) -> np.ndarray:
    """A marker's 4 corners in ArUco's order (top-left, top-right, bottom-right,
    bottom-left) for a marker centred at (cx, cy) whose top edge faces ``heading``."""
    up = np.array([math.cos(heading), math.sin(heading)])
    left = np.array([-up[1], up[0]])
    h = side / 2.0
    c = np.array([cx, cy])
    return np.array(
        [c + h * (up + left), c + h * (up - left), c - h * (up + left), c + h * (left - up)]
    )
