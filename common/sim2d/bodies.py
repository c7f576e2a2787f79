"""pymunk bodies, shapes and joints of a Sim2D world's things, in millimetres and grams.

How each kind of thing is made physical (the thesis's collision rules through
pymunk): obstacles are static; a robot is a dynamic disc pulled by a kinematic
control body through force-limited pivot and gear joints (pymunk's tank
pattern), with its gripper's tongs as two more shapes of its body; a movable
object is a dynamic body held to the floor by force-limited joints (top-down
friction). The world adds what these return to its space and keeps the rules
of when they may be added.
"""

from __future__ import annotations

import pymunk

from common.sim2d.collision import (
    CAT_ALL,
    CAT_OBJECT,
    CAT_OBSTACLE,
    CAT_ROBOT,
    CAT_TONGS,
    COLL_OBJECT,
    COLL_ROBOT,
    COLL_TONGS,
)
from common.sim2d.entities import Agent, ShapeSpec
from common.sim2d.specs import AgentTypeSpec

GRAVITY_MM_S2 = 9810.0
WALL_THICKNESS_MM = 20.0
FRICTION = 0.3  # shape-to-shape friction of walls, obstacles and robots


def shapes_of(body: pymunk.Body, shape: ShapeSpec) -> list[pymunk.Shape]:
    if shape.kind == "circle":
        return [pymunk.Circle(body, shape.radius_mm)]
    return [pymunk.Poly(body, shape.vertices())]


def walls(static: pymunk.Body, width: float, height: float) -> list[pymunk.Shape]:
    """Four boxes just outside the arena's edges."""
    t, w, h = WALL_THICKNESS_MM, width, height
    boxes = [
        (-t, -t, w + t, 0.0),
        (-t, h, w + t, h + t),
        (-t, 0.0, 0.0, h),
        (w, 0.0, w + t, h),
    ]
    out: list[pymunk.Shape] = []
    for x0, y0, x1, y1 in boxes:
        poly = pymunk.Poly(static, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
        poly.filter = pymunk.ShapeFilter(categories=CAT_OBSTACLE)
        poly.friction = FRICTION
        out.append(poly)
    return out


def _placed(
    body: pymunk.Body, shape: ShapeSpec, x: float, y: float, heading: float, category: int
) -> list[pymunk.Shape]:
    """``body`` put at (x, y, heading); ``shape``'s pymunk shapes on it, in ``category``."""
    body.position = (x, y)
    body.angle = heading
    shapes = shapes_of(body, shape)
    for s in shapes:
        s.filter = pymunk.ShapeFilter(categories=category)
    return shapes


def obstacle(
    shape: ShapeSpec, x: float, y: float, heading: float
) -> tuple[pymunk.Body, list[pymunk.Shape]]:
    body = pymunk.Body(body_type=pymunk.Body.STATIC)
    shapes = _placed(body, shape, x, y, heading, CAT_OBSTACLE)
    for s in shapes:
        s.friction = FRICTION
    return body, shapes


def movable_object(
    shape: ShapeSpec, x: float, y: float, heading: float, mass_g: float
) -> tuple[pymunk.Body, list[pymunk.Shape]]:
    if shape.kind == "circle":
        moment = pymunk.moment_for_circle(mass_g, 0, shape.radius_mm)
    else:
        moment = pymunk.moment_for_poly(mass_g, shape.vertices())
    body = pymunk.Body(mass_g, moment)
    shapes = _placed(body, shape, x, y, heading, CAT_OBJECT)
    for s in shapes:
        s.collision_type = COLL_OBJECT
        s.friction = 0.4
    return body, shapes


def floor_friction(
    static: pymunk.Body, body: pymunk.Body, mass_g: float, mu: float, shape: ShapeSpec
) -> list[pymunk.Constraint]:
    """Top-down friction (pymunk's tank pattern): velocity-only joints to the floor."""
    pivot = pymunk.PivotJoint(static, body, (0, 0), (0, 0))
    pivot.max_bias = 0.0
    pivot.max_force = mu * mass_g * GRAVITY_MM_S2
    gear = pymunk.GearJoint(static, body, 0.0, 1.0)
    gear.max_bias = 0.0
    gear.max_force = mu * mass_g * GRAVITY_MM_S2 * shape.bounding_radius_mm / 2
    return [pivot, gear]


def agent(
    ident: str,
    spec: AgentTypeSpec,
    group: int,
    x: float,
    y: float,
    heading: float,
    gripper: bool,
    joints: bool = True,
    tongs_mask: int = CAT_ALL,
) -> Agent:
    """A robot's disc, (``joints``) control body and joints, (``gripper``) tongs.

    Not yet in a space. Without ``joints`` (the velocity drive) the world's
    compiled tick drives the disc itself with a force-limited servo
    (kernels.servo_forces), with the same force and torque limits. ``tongs_mask``:
    what lowered tongs collide with (collision.TONGS_MASK_LIGHT for that drive).
    """
    r = spec.radius_mm
    body = pymunk.Body(spec.mass_g, pymunk.moment_for_circle(spec.mass_g, 0, r))
    body.position = (x, y)
    body.angle = heading
    circle = pymunk.Circle(body, r)
    circle.filter = pymunk.ShapeFilter(group=group, categories=CAT_ROBOT)
    circle.collision_type = COLL_ROBOT
    circle.friction = FRICTION
    if not joints:
        robot = Agent(ident, spec, group, gripper, spec.colour, body, None, circle)
    else:
        control = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
        control.position = (x, y)
        control.angle = heading
        pivot = pymunk.PivotJoint(control, body, (0, 0), (0, 0))
        pivot.max_bias = 0.0  # velocity only: the pivot never yanks the robot back
        pivot.max_force = spec.drive.max_force
        gear = pymunk.GearJoint(control, body, 0.0, 1.0)
        gear.error_bias = 0.0
        gear.max_bias = 0.0
        gear.max_force = spec.drive.max_torque
        robot = Agent(ident, spec, group, gripper, spec.colour, body, control, circle)
        robot.joints = [pivot, gear]
    if gripper and spec.gripper is not None:
        g = spec.gripper
        for side in (1.0, -1.0):
            y0 = side * g.gap_mm / 2
            y1 = side * (g.gap_mm / 2 + g.tong_width_mm)
            x0, x1 = g.tong_x_mm
            tong = pymunk.Poly(body, [(x0, y0), (x1, y0), (x1, y1), (x0, y1)])
            tong.filter = pymunk.ShapeFilter(group=group, categories=CAT_TONGS, mask=tongs_mask)
            tong.collision_type = COLL_TONGS
            tong.friction = FRICTION
            robot.tongs.append(tong)
    return robot


def id_of(body: pymunk.Body) -> int:
    """A body's key in the world's body -> thing maps."""
    return int(body.id)
