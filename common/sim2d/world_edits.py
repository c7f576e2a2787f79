"""A World's live edits: add, move, rotate, remove anything and resize the arena, by the rules.

Every edit is validated (inside the arena; no agent or object overlapping an
obstacle; no obstacle onto an agent) and undone if it breaks a rule, raising
:class:`EditError` with the reason; each change of the layout bumps
``World.layout`` so a viewer refetches the snapshot.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import pymunk

from common.sim2d import bodies, world_discs
from common.sim2d.bodies import id_of
from common.sim2d.collision import CAT_OBSTACLE, CAT_ROBOT
from common.sim2d.entities import (
    Agent,
    Light,
    LightMode,
    MovableObject,
    Obstacle,
    ShapeSpec,
    Zone,
)
from common.sim2d.specs import AgentTypeSpec
from common.sim2d.world_state import EditError

if TYPE_CHECKING:
    import numpy as np

    from common.sim2d.gripper import GripperTurrets
    from common.sim2d.sensing import SensorSuite
    from common.sim2d.world_state import WorldState


class WorldEdits:
    """World's edit methods (a mixin of :class:`~common.sim2d.world.World`)."""

    if TYPE_CHECKING:  # the World's state and model these edit (common/sim2d/world.py)
        state: WorldState
        width: float
        height: float
        drive: str
        layout: int
        space: pymunk.Space
        sensors: SensorSuite
        grippers: GripperTurrets
        tongs_mask: int
        agents: list[Agent]
        obstacles: dict[str, Obstacle]
        objects: list[MovableObject]
        lights: list[Light]
        zones: dict[str, Zone]
        homes: dict[str, tuple[float, float, float]]
        agent_pose: np.ndarray

        def ids(self) -> set[str]: ...

        def agent_slot(self, agent_id: str) -> int: ...

        def find_object(self, ident: str) -> MovableObject | None: ...

    # -- arena -------------------------------------------------------------------

    def resize(self, width_mm: float, height_mm: float) -> None:
        if not (width_mm > 0 and height_mm > 0):
            raise EditError("the arena's width and height must be positive")
        old = (self.width, self.height)
        self.width, self.height = float(width_mm), float(height_mm)
        outside = [i for i in self.ids() if not self._inside_arena_id(i)]
        if outside:
            self.width, self.height = old
            raise EditError(
                f"the arena {width_mm:.0f} x {height_mm:.0f} mm would leave outside: "
                + ", ".join(sorted(outside)[:10])
            )
        self.state.build_walls()
        self.layout += 1

    def _inside(self, pts: Iterable[tuple[float, float]], margin: float = 0.0) -> bool:
        return all(
            x - margin >= -1e-6
            and x + margin <= self.width + 1e-6
            and y - margin >= -1e-6
            and y + margin <= self.height + 1e-6
            for x, y in pts
        )

    def _shape_inside(self, shape: ShapeSpec, x: float, y: float, heading: float) -> bool:
        if shape.kind == "circle":
            return self._inside([(x, y)], shape.radius_mm)
        return self._inside(shape.world_vertices(x, y, heading))

    def _inside_arena_id(self, ident: str) -> bool:
        x, y, heading = self.pose_of(ident)
        shape = self.shape_of(ident)
        return shape is None or self._shape_inside(shape, x, y, heading)

    # -- obstacles ------------------------------------------------------------------

    def add_obstacle(
        self,
        ident: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        colour: str = "#808080",
    ) -> Obstacle:
        self.state.check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"obstacle {ident} would stick out of the arena")
        body, shapes = bodies.obstacle(shape, x, y, heading)
        self.space.add(body, *shapes)
        overlapping = self._agents_touching(shapes)
        if overlapping:
            self.space.remove(body, *shapes)
            raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
        obstacle = Obstacle(ident, shape, x, y, heading, colour, body, shapes)
        self.obstacles[ident] = obstacle
        self.sensors.obstacles_changed()
        self.layout += 1
        return obstacle

    def _place_bodies(self) -> None:
        """On the discs drive, put the robots' and objects' bodies where they are (a query's need).

        Chipmunk is not stepped on that drive (common/sim2d/world_discs.py).
        """
        world_discs.place_bodies(self.state)

    def _agents_touching(self, shapes: list[pymunk.Shape]) -> list[str]:
        self._place_bodies()
        found = []
        for shape in shapes:
            for info in self.space.shape_query(shape):
                body = info.shape.body if info.shape else None  # a shape in the space has one
                agent = self.state.agent_by_body.get(id_of(body)) if body is not None else None
                if agent is not None and info.shape is agent.shape:
                    found.append(agent.id)
        return sorted(set(found))

    # -- movable objects -----------------------------------------------------------------

    def add_object(
        self,
        ident: str,
        kind: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        *,
        mass_g: float = 10.0,
        friction: float = 0.5,
        resistivity: int = 128,
        colour: str = "#ff8c00",
    ) -> MovableObject:
        self.state.check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"object {ident} would stick out of the arena")
        if mass_g <= 0:
            raise EditError(f"object {ident}: mass must be positive")
        body, shapes = bodies.movable_object(shape, x, y, heading, mass_g)
        if self._blocked(shapes, CAT_OBSTACLE | CAT_ROBOT, body):
            raise EditError(f"object {ident} would overlap an obstacle or an agent")
        obj = MovableObject(ident, kind, shape, mass_g, friction, resistivity, colour, body, shapes)
        obj.floor_joints = bodies.floor_friction(
            self.space.static_body, body, mass_g, friction, shape
        )
        self.space.add(body, *shapes, *obj.floor_joints)
        self.objects.append(obj)
        self.state.object_by_body[id_of(body)] = obj
        self._sync_tongs()
        self.layout += 1
        return obj

    def _sync_tongs(self) -> None:
        """Tongs into the space, or out of it, as the objects they could touch come and go."""
        wanted = self.drive == "joints" or bool(self.objects)
        if wanted == self.state.tongs_in:
            return
        tongs = [tong for agent in self.agents for tong in agent.tongs]
        if tongs:
            if wanted:
                self.space.add(*tongs)
            else:
                self.space.remove(*tongs)
        self.state.tongs_in = wanted

    def _blocked(self, shapes: list[pymunk.Shape], mask: int, body: pymunk.Body) -> bool:
        self._place_bodies()
        for shape in shapes:
            shape.cache_bb()
            for info in self.space.shape_query(shape):
                other = info.shape
                if other is None or other.body is body:
                    continue
                points = info.contact_point_set.points
                # A real overlap, not two shapes merely touching.
                if (
                    other.filter.categories & mask
                    and points
                    and min(p.distance for p in points) < -0.5
                ):
                    return True
        return False

    # -- lights and zones ---------------------------------------------------------------

    def add_light(
        self,
        ident: str,
        x: float,
        y: float,
        *,
        intensity: float = 1.0,
        radius_mm: float = 300.0,
        mode: LightMode = "on",
        period_s: float = 1.0,
        colour: str = "#ffd700",
    ) -> Light:
        self.state.check_new_id(ident)
        if not self._inside([(x, y)]):
            raise EditError(f"light {ident} is outside the arena")
        if period_s <= 0 or radius_mm <= 0 or intensity < 0:
            raise EditError(f"light {ident}: period and radius must be positive, intensity >= 0")
        light = Light(ident, x, y, intensity, radius_mm, mode, period_s, colour)
        self.lights.append(light)
        self.layout += 1
        return light

    def add_zone(
        self,
        ident: str,
        kind: str,
        shape: ShapeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        colour: str = "#c8e6c9",
    ) -> Zone:
        self.state.check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"zone {ident} would stick out of the arena")
        zone = Zone(ident, kind, shape, x, y, heading, colour)
        self.zones[ident] = zone
        self.layout += 1
        return zone

    # -- agents ----------------------------------------------------------------------

    def add_agent(
        self,
        ident: str,
        spec: AgentTypeSpec,
        x: float,
        y: float,
        heading: float = 0.0,
        *,
        gripper: bool = True,
        colour: str | None = None,
        defer_tables: bool = False,
    ) -> Agent:
        """Add a robot. ``defer_tables``: the caller adds many, then calls finish_agents()."""
        self.state.check_new_id(ident)
        r = spec.radius_mm
        if not self._inside([(x, y)], r):
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would stick out of the arena")
        hits = self.space.point_query((x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE))
        if hits:
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle")
        self.state.serial += 1
        fitted = gripper and spec.gripper is not None
        agent = bodies.agent(
            ident,
            spec,
            self.state.serial,
            x,
            y,
            heading,
            fitted,
            joints=self.drive == "joints",
            tongs_mask=self.tongs_mask,
        )
        agent.colour = colour or spec.colour
        self.space.add(*agent.physics(tongs=self.state.tongs_in))
        self.agents.append(agent)
        self.state.agent_by_body[id_of(agent.body)] = agent
        arm = float(spec.gripper.arm_down) if spec.gripper else 0.0
        self.state.append_agent_rows((x, y, heading), arm)
        self.homes[ident] = (float(x), float(y), float(heading))
        if not defer_tables:
            self.state.rebuild_tables()
        self.layout += 1
        return agent

    def finish_agents(self) -> None:
        """Rebuild the per-agent tables after add_agent(..., defer_tables=True)."""
        self.state.rebuild_tables()

    # -- generic edits ------------------------------------------------------------------

    def pose_of(self, ident: str) -> tuple[float, float, float]:
        for slot, agent in enumerate(self.agents):
            if agent.id == ident:
                x, y, h = self.agent_pose[slot]
                return float(x), float(y), float(h)
        for obj in self.objects:
            if obj.id == ident and obj.body is not None:
                self._place_bodies()  # the discs drive moves objects in its arrays
                return obj.body.position.x, obj.body.position.y, obj.body.angle
        if ident in self.obstacles:
            o = self.obstacles[ident]
            return o.x, o.y, o.heading
        if ident in self.zones:
            z = self.zones[ident]
            return z.x, z.y, z.heading
        for light in self.lights:
            if light.id == ident:
                return light.x, light.y, 0.0
        raise EditError(f"no object named {ident!r} in this world")

    def shape_of(self, ident: str) -> ShapeSpec | None:
        for agent in self.agents:
            if agent.id == ident:
                return ShapeSpec.circle(agent.spec.radius_mm)
        obj = self.find_object(ident)
        if obj is not None:
            return obj.shape
        if ident in self.obstacles:
            return self.obstacles[ident].shape
        if ident in self.zones:
            return self.zones[ident].shape
        return None  # lights are points

    def move(self, ident: str, x: float, y: float, heading: float | None = None) -> None:
        """Move (and optionally rotate) anything; validated, undone if it breaks a rule."""
        old = self.pose_of(ident)  # an object's places the bodies first (discs drive)
        heading = old[2] if heading is None else heading
        shape = self.shape_of(ident)
        if shape is not None and not self._shape_inside(shape, x, y, heading):
            raise EditError(f"{ident} would stick out of the arena at ({x:.0f}, {y:.0f})")
        if shape is None and not self._inside([(x, y)]):
            raise EditError(f"{ident} would be outside the arena at ({x:.0f}, {y:.0f})")
        for light in self.lights:
            if light.id == ident:
                light.x, light.y = x, y
                self.layout += 1
                return
        if ident in self.zones:
            z = self.zones[ident]
            z.x, z.y, z.heading = x, y, heading
            self.layout += 1
            return
        if ident in self.obstacles:
            o = self.obstacles[ident]
            assert o.body is not None
            o.body.position, o.body.angle = (x, y), heading
            self.space.reindex_shapes_for_body(o.body)
            overlapping = self._agents_touching(o.shapes)
            if overlapping:
                o.body.position, o.body.angle = (o.x, o.y), o.heading
                self.space.reindex_shapes_for_body(o.body)
                raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
            o.x, o.y, o.heading = x, y, heading
            self.sensors.obstacles_changed()
            self.layout += 1
            return
        for slot, agent in enumerate(self.agents):
            if agent.id == ident:
                r = agent.spec.radius_mm
                hits = self.space.point_query(
                    (x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE)
                )
                if hits:
                    raise EditError(
                        f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle"
                    )
                for b in (agent.body, agent.control):
                    if b is None:
                        continue
                    b.position, b.angle = (x, y), heading
                    b.velocity, b.angular_velocity = (0, 0), 0.0
                self.space.reindex_shapes_for_body(agent.body)
                self.agent_pose[slot] = (x, y, heading)
                self.layout += 1
                return
        obj = self.find_object(ident)
        if obj is not None and obj.body is not None:
            if obj.held_by is not None:
                self.grippers.release(obj)
            old_pos, old_angle = obj.body.position, obj.body.angle
            obj.body.position, obj.body.angle = (x, y), heading
            self.space.reindex_shapes_for_body(obj.body)
            if self._blocked(obj.shapes, CAT_OBSTACLE, obj.body):
                obj.body.position, obj.body.angle = old_pos, old_angle
                self.space.reindex_shapes_for_body(obj.body)
                raise EditError(f"object {ident} would overlap an obstacle at ({x:.0f}, {y:.0f})")
            obj.body.velocity, obj.body.angular_velocity = (0, 0), 0.0
            self.layout += 1
            return
        raise EditError(f"no object named {ident!r} in this world")

    def set_home(self, ident: str) -> None:
        """Make an agent's current pose its start pose (a map editor placed it)."""
        if ident in self.homes:
            self.homes[ident] = self.pose_of(ident)

    def reset_agent(self, ident: str) -> tuple[float, float, float]:
        """Put an agent back at its start pose, at rest; returns the pose."""
        home = self.homes.get(ident)
        if home is None:
            raise EditError(f"no agent named {ident!r} in this world")
        self.move(ident, *home)
        return home

    def rotate(self, ident: str, heading: float) -> None:
        x, y, _ = self.pose_of(ident)
        self.move(ident, x, y, heading)

    def remove(self, ident: str) -> None:
        if ident in self.obstacles:
            o = self.obstacles.pop(ident)
            assert o.body is not None  # set when it was added to this world
            self.space.remove(o.body, *o.shapes)
            self.sensors.obstacles_changed()
        elif ident in self.zones:
            del self.zones[ident]
        elif any(light.id == ident for light in self.lights):
            self.lights = [light for light in self.lights if light.id != ident]
        elif (obj := self.find_object(ident)) is not None:
            if obj.held_by is not None:
                self.grippers.release(obj)
            assert obj.body is not None  # set when it was added to this world
            self.space.remove(obj.body, *obj.shapes, *obj.floor_joints)
            self.objects.remove(obj)
            self.state.object_by_body.pop(id_of(obj.body), None)
            self._sync_tongs()
        else:
            try:
                slot = self.agent_slot(ident)
            except KeyError:
                raise EditError(f"no object named {ident!r} in this world") from None
            agent = self.agents[slot]
            if agent.held is not None:
                self.grippers.release(agent.held)
            self.space.remove(*agent.physics(tongs=self.state.tongs_in))
            del self.agents[slot]
            self.homes.pop(ident, None)
            self.state.agent_by_body.pop(id_of(agent.body), None)
            self.state.delete_agent_rows(slot)
            self.state.rebuild_tables()
        self.layout += 1
