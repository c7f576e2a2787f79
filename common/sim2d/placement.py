"""Where a new robot can stand: the free spot nearest to where the user asked.

"Add robot" asks for the arena's centre (or where the user clicked); a rock, a
ball or another robot may be there. The search looks at the asked point, then
on rings around it, each a step further out, and takes the first point where the
robot's disc lies inside the arena and clear of obstacles, movable objects and
robots. Objects count by their bounding circle: a spot beside a crate is never
one a robot would overlap it at.
"""

from __future__ import annotations

import math

import numpy as np
import pymunk

from common.sim2d.collision import CAT_OBSTACLE
from common.sim2d.world import World

CLEARANCE_MM = 5.0  # between the new robot and anything: no contact at its first tick


def _discs(world: World) -> np.ndarray:
    """(N, 3): x, y, radius of every robot and movable object (mm)."""
    rows = [(*world.pose_of(a.id)[:2], a.spec.radius_mm) for a in world.agents]
    rows += [(*world.pose_of(o.id)[:2], o.shape.bounding_radius_mm) for o in world.objects]
    return np.asarray(rows, np.float64).reshape(-1, 3)


def free_spot(world: World, radius_mm: float, x: float, y: float) -> tuple[float, float] | None:
    """The point nearest to (x, y), to within a step of half the robot's radius, where a
    robot of ``radius_mm`` stands clear of everything; None if the arena has no room."""
    reach = radius_mm + CLEARANCE_MM
    if 2 * reach > min(world.width, world.height):
        return None
    discs = _discs(world)
    only_obstacles = pymunk.ShapeFilter(mask=CAT_OBSTACLE)
    # The asked point, pulled inside the arena: a click on the wall means beside it.
    cx = min(max(x, reach), world.width - reach)
    cy = min(max(y, reach), world.height - reach)
    step = max(radius_mm / 2, 5.0)
    farthest = math.hypot(world.width, world.height)
    ring = 0
    while ring * step <= farthest:
        r = ring * step
        count = 1 if ring == 0 else max(8, math.ceil(2 * math.pi * r / step))
        angles = np.arange(count) * (2 * math.pi / count)
        px, py = cx + r * np.cos(angles), cy + r * np.sin(angles)
        ok = (px >= reach) & (px <= world.width - reach)
        ok &= (py >= reach) & (py <= world.height - reach)
        if len(discs) and ok.any():  # every robot and object against the whole ring at once
            gaps = np.hypot(px[:, None] - discs[:, 0], py[:, None] - discs[:, 1]) - discs[:, 2]
            ok &= gaps.min(axis=1) >= reach
        for k in np.flatnonzero(ok):
            spot = (float(px[k]), float(py[k]))
            if not world.space.point_query(spot, reach, only_obstacles):
                return spot
        ring += 1
    return None
