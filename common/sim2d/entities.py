"""The things a world holds: shapes, obstacles, movable objects, lights, zones, agents.

Plain data plus their pymunk handles. The :class:`~common.sim2d.world.World`
creates and owns them; nothing else mutates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import pymunk

from common.sim2d.specs import AgentTypeSpec

ShapeKind = Literal["circle", "box", "polygon"]
LightMode = Literal["on", "off", "blink"]


@dataclass(frozen=True)
class ShapeSpec:
    """A 2D outline in its own frame (mm): a circle, a box centred on the origin, or a polygon."""

    kind: ShapeKind
    radius_mm: float = 0.0
    width_mm: float = 0.0
    height_mm: float = 0.0
    points_mm: tuple[tuple[float, float], ...] = ()

    @classmethod
    def circle(cls, radius_mm: float) -> ShapeSpec:
        return cls("circle", radius_mm=radius_mm)

    @classmethod
    def box(cls, width_mm: float, height_mm: float) -> ShapeSpec:
        return cls("box", width_mm=width_mm, height_mm=height_mm)

    def vertices(self) -> list[tuple[float, float]]:
        """Polygon vertices (counter-clockwise) in the shape's frame; empty for a circle."""
        if self.kind == "box":
            w, h = self.width_mm / 2, self.height_mm / 2
            return [(-w, -h), (w, -h), (w, h), (-w, h)]
        if self.kind == "polygon":
            return list(self.points_mm)
        return []

    @property
    def bounding_radius_mm(self) -> float:
        if self.kind == "circle":
            return self.radius_mm
        return max(math.hypot(x, y) for x, y in self.vertices())

    def world_vertices(self, x: float, y: float, heading: float) -> list[tuple[float, float]]:
        c, s = math.cos(heading), math.sin(heading)
        return [(x + c * px - s * py, y + s * px + c * py) for px, py in self.vertices()]

    def area_mm2(self) -> float:
        if self.kind == "circle":
            return math.pi * self.radius_mm**2
        pts = self.vertices()
        return abs(
            sum(a[0] * b[1] - b[0] * a[1] for a, b in zip(pts, pts[1:] + pts[:1], strict=True)) / 2
        )


@dataclass
class Obstacle:
    """Immovable: walls, boxes, any polygon. Never pushed."""

    id: str
    shape: ShapeSpec
    x: float
    y: float
    heading: float
    colour: str
    body: pymunk.Body | None = None
    shapes: list[pymunk.Shape] = field(default_factory=list)


@dataclass
class MovableObject:
    """Inert, pushed by agents, obstacles and other objects; can be gripped."""

    id: str
    kind: str  # "ball", "box", "cylinder", ...: for viewers and maps
    shape: ShapeSpec
    mass_g: float
    friction: float  # top-down (floor) friction coefficient
    resistivity: int  # what the gripper's resistivity sensor reads (0..255)
    colour: str
    body: pymunk.Body | None = None
    shapes: list[pymunk.Shape] = field(default_factory=list)
    floor_joints: list[pymunk.Constraint] = field(default_factory=list)
    held_by: Agent | None = None
    held_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # x, y, heading in holder frame


@dataclass
class Light:
    """A lamp; on, off, or blinking with ``period_s`` (on for the first half)."""

    id: str
    x: float
    y: float
    intensity: float  # 1.0: a bright lamp (drives Khepera ambient to about 50 up close)
    radius_mm: float  # beyond this distance it does not register
    mode: LightMode
    period_s: float
    colour: str

    # Counts every attribute set on any light, its construction's included: the
    # sensors keep the lit lights' table while no light changed (SensorSuite.lit),
    # and an edit made straight on a light (light.x = ...) still shows.
    edits: ClassVar[int] = 0

    def __setattr__(self, name: str, value: object) -> None:
        object.__setattr__(self, name, value)
        Light.edits += 1

    def is_on(self, sim_time: float) -> bool:
        if self.mode == "blink":
            return (sim_time % self.period_s) < self.period_s / 2
        return self.mode == "on"


@dataclass
class Zone:
    """A marked floor area (a nest, a goal): drawn and saved, never collides."""

    id: str
    kind: str
    shape: ShapeSpec
    x: float
    y: float
    heading: float
    colour: str

    def contains(self, x: float, y: float) -> bool:
        """Whether the point (mm) lies in the zone's outline (episodes and real attempts)."""
        if self.shape.kind == "circle":
            return math.hypot(x - self.x, y - self.y) <= self.shape.radius_mm
        pts = self.shape.world_vertices(self.x, self.y, self.heading)
        inside = False
        for (ax, ay), (bx, by) in zip(pts, pts[1:] + pts[:1], strict=True):
            if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
                inside = not inside
        return inside


@dataclass
class Agent:
    """A robot: a dynamic disc, driven through joints to a kinematic control body
    (pymunk's tank pattern, the "joints" drive) or by a force servo (the
    "velocity" drive: no control body, no joints)."""

    id: str
    spec: AgentTypeSpec
    serial: int  # unique within the world; the collision group of its shapes
    gripper_fitted: bool
    colour: str
    body: pymunk.Body
    control: pymunk.Body | None  # None with the velocity drive
    shape: pymunk.Shape
    tongs: list[pymunk.Shape] = field(default_factory=list)
    joints: list[pymunk.Constraint] = field(default_factory=list)
    held: MovableObject | None = None

    @property
    def has_gripper(self) -> bool:
        return self.gripper_fitted and self.spec.gripper is not None

    def physics(self, tongs: bool = True) -> list[pymunk.Body | pymunk.Shape | pymunk.Constraint]:
        """Everything of this robot that is in the world's space (``tongs``: with them)."""
        control = [] if self.control is None else [self.control]
        return [self.body, *control, self.shape, *(self.tongs if tongs else []), *self.joints]
