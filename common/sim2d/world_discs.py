"""A discs world's movable objects as the drive's arrays, and back to their pymunk bodies.

On the discs drive chipmunk is never stepped: the objects move in the arrays
of :class:`DiscObjects` (common/sim2d/pucks.py's layout), in place, tick after
tick. Their pymunk bodies stay for the edits' overlap queries and the
gripper's geometry, and are put where the arrays say (with their velocities)
only when something asks (:func:`place_bodies`, as the robots' bodies are).
The arrays are rebuilt from the bodies, so nothing is lost, whenever the
objects, the robots or a grip change (:func:`disc_objects`' key).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from common.sim2d import pucks_tables as pucks

if TYPE_CHECKING:
    from common.sim2d.entities import MovableObject
    from common.sim2d.world_state import WorldState


@dataclass(frozen=True)
class DiscObjects:
    """The objects of one layout in the drive's layout (pucks.objects_table)."""

    key: tuple[object, ...]
    objects: list[MovableObject]  # the world's objects these rows are, in order
    table: tuple[np.ndarray, ...]  # pucks.objects_table: pose and vel move in place
    radius: np.ndarray  # (N + K,) the discs' radii: the robots', then the objects'
    # (N + K,) how the solver shares a push: the robots' masses, the objects'
    # resistance in those units (disc_objects); a held object's adds its holder's.
    mass: np.ndarray
    holding: np.ndarray  # (N,) bool: which robots hold an object
    edges: int  # how many edges the objects that are not round have


def _key(state: WorldState) -> tuple[object, ...]:
    return (state.layout, state.grip_version, state.tables, state.fingers, state.arm)


def current(state: WorldState) -> DiscObjects | None:
    """The arrays as they are, or None if they must be rebuilt (no rebuild)."""
    d = state.discs
    if d is None:
        return None
    k = d.key
    if (
        k[0] == state.layout
        and k[1] == state.grip_version
        and k[2] is state.tables
        and k[3] is state.fingers
        and k[4] is state.arm
    ):
        return d
    return None


def disc_objects(state: WorldState) -> DiscObjects:
    """The objects' arrays for this tick, rebuilt from the bodies if anything changed."""
    d = current(state)
    if d is not None:
        return d
    place_bodies(state)  # the old arrays' state into the bodies first
    objs = list(state.objects)
    n, k = len(state.agents), len(objs)
    (pose, vel, decel, holder, offset, grip, _, is_round, _, vstart, own_r) = pucks.objects_table(
        k, n
    )
    slot_of = state.slot_of
    verts: list[tuple[float, float]] = []
    radius = np.concatenate([state.tables.radius, np.zeros(k)])
    mass = np.concatenate([state.tables.mass, np.zeros(k)])
    holding = np.zeros(n, dtype=bool)
    # How hard an object resists a push, in the robots' mass units: its floor
    # friction (mu m g) over what a robot's motors push with (max_force), times a
    # robot's mass. Two robots share a push by mass; a robot and an object by
    # this, so a light object goes where the robot drives it (the joints drive's
    # motors, 2e6 g mm/s^2, never feel a 20 g box's 1e5 of friction) and a
    # heavy one slows it. The robots' median ratio: one number for the world.
    t = state.tables
    ratio = float(np.median(t.mass / t.servo[:, 2])) if n else 1.0 / 2.0e6 * 70.0
    for j, obj in enumerate(objs):
        body = obj.body
        assert body is not None  # set when it was added to this world
        pose[j] = (body.position.x, body.position.y, body.angle)
        vel[j] = (body.velocity.x, body.velocity.y, 0.0)
        decel[j] = obj.friction * pucks.FLOOR_G_MM_S2
        radius[n + j] = obj.shape.bounding_radius_mm
        mass[n + j] = max(obj.friction * pucks.FLOOR_G_MM_S2 * ratio, 1e-3) * obj.mass_g
        is_round[j] = obj.shape.kind == "circle"
        own_r[j] = obj.shape.radius_mm
        if not is_round[j]:
            verts.extend(obj.shape.vertices())
        vstart[j + 1] = len(verts)
        if obj.held_by is not None:
            slot = slot_of(obj.held_by)
            holder[j] = slot
            offset[j] = obj.held_offset
            holding[slot] = True
            # Held, it moves with its holder: a push on it is a push on both.
            mass[n + j] += state.tables.mass[slot]
            vel[j] = 0.0
    for slot, agent in enumerate(state.agents):
        g = agent.spec.gripper
        if agent.has_gripper and g is not None:
            grip[slot] = (g.grip_x_mm[0], g.grip_x_mm[1], g.gap_mm / 2, g.lowered_above)
        else:
            grip[slot] = (0.0, -1.0, 0.0, np.inf)
    table = (
        pose,
        vel,
        decel,
        holder,
        offset,
        grip,
        state.fingers,
        is_round,
        np.array(verts, dtype=np.float64).reshape(-1, 2),
        vstart,
        own_r,
    )
    d = state.discs = DiscObjects(_key(state), objs, table, radius, mass, holding, len(verts))
    return d


def place_bodies(state: WorldState) -> None:
    """Put the robots' and the objects' pymunk bodies where the drive's arrays have them.

    Chipmunk is not stepped on this drive, so the bodies stay where an edit last
    put them; an edit that asks the space what a shape overlaps, or the gripper
    asking where an object is, needs them where the things are.
    """
    if state.drive != "discs" or state.bodies_placed:
        return
    for slot, agent in enumerate(state.agents):
        x, y, heading = state.agent_pose[slot]
        agent.body.position, agent.body.angle = (float(x), float(y)), float(heading)
        state.space.reindex_shapes_for_body(agent.body)
    d = state.discs
    if d is not None:
        pose, vel = d.table[0], d.table[1]
        for j, obj in enumerate(d.objects):
            body = obj.body
            if body is None or obj not in state.objects:
                continue  # removed since: nothing to place
            body.position, body.angle = (float(pose[j, 0]), float(pose[j, 1])), float(pose[j, 2])
            body.velocity = (float(vel[j, 0]), float(vel[j, 1]))
            state.space.reindex_shapes_for_body(body)
    state.bodies_placed = True


def touching(state: WorldState, slot: int, tolerance_mm: float = 0.5) -> set[tuple[str, str]]:
    """What robot ``slot``'s disc touches: ("wall", ""), ("obstacle" | "robot" | "object", id).

    Chipmunk's arbiters say it on the other drives (the runner's dry run reads
    them); here there are none, so it is measured: within ``tolerance_mm`` of
    the disc. An object counts as its solver disc; one held with a raised arm
    touches nothing, and the robot's own never counts.
    """
    x, y, _ = (float(v) for v in state.agent_pose[slot])
    r = float(state.tables.radius[slot])
    reach = r + tolerance_mm
    found: set[tuple[str, str]] = set()
    if min(x, y, state.width - x, state.height - y) <= reach:
        found.add(("wall", ""))
    for ident, o in state.obstacles.items():
        if o.shape.kind == "circle":
            if math.hypot(x - o.x, y - o.y) <= reach + o.shape.radius_mm:
                found.add(("obstacle", ident))
            continue
        pts = o.shape.world_vertices(o.x, o.y, o.heading)
        if _inside(x, y, pts) or any(
            _to_segment(x, y, a, b) <= reach for a, b in zip(pts, pts[1:] + pts[:1], strict=True)
        ):
            found.add(("obstacle", ident))
    for other, agent in enumerate(state.agents):
        if other != slot:
            ox, oy = state.agent_pose[other, :2]
            if math.hypot(x - ox, y - oy) <= reach + float(state.tables.radius[other]):
                found.add(("robot", agent.id))
    me = state.agents[slot]
    for j, obj in enumerate(state.objects):
        if obj.held_by is me or not state.on_floor(obj):
            continue
        ox, oy = state.object_pose[j, :2]
        if math.hypot(x - ox, y - oy) <= reach + obj.shape.bounding_radius_mm:
            found.add(("object", obj.id))
    return found


def _to_segment(x: float, y: float, a: tuple[float, float], b: tuple[float, float]) -> float:
    ex, ey = b[0] - a[0], b[1] - a[1]
    length2 = ex * ex + ey * ey
    u = 0.0 if length2 == 0 else min(max(((x - a[0]) * ex + (y - a[1]) * ey) / length2, 0.0), 1.0)
    return math.hypot(x - (a[0] + u * ex), y - (a[1] + u * ey))


def _inside(x: float, y: float, pts: list[tuple[float, float]]) -> bool:
    """Whether (x, y) is inside the polygon (even-odd rule)."""
    inside = False
    for (ax, ay), (bx, by) in zip(pts, pts[1:] + pts[:1], strict=True):
        if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside
