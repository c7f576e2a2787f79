"""A world's editor: add, move, rotate, remove anything and resize the arena, by the rules.

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
    from common.sim2d.gripper import GripperTurrets
    from common.sim2d.world_state import WorldState


class WorldEditor:
    """Edits one world's state by the rules: each edit validated, and undone if it breaks one."""

    def __init__(self, state: WorldState, grippers: GripperTurrets) -> None:
        self._state = state
        self._grippers = grippers  # a moved or removed object is released first

    # -- arena -------------------------------------------------------------------

    def resize(self, width_mm: float, height_mm: float) -> None:
        s = self._state
        if not (width_mm > 0 and height_mm > 0):
            raise EditError("the arena's width and height must be positive")
        old = (s.width, s.height)
        s.width, s.height = float(width_mm), float(height_mm)
        outside = [i for i in s.ids() if not self._inside_arena_id(i)]
        if outside:
            s.width, s.height = old
            raise EditError(
                f"the arena {width_mm:.0f} x {height_mm:.0f} mm would leave outside: "
                + ", ".join(sorted(outside)[:10])
            )
        s.build_walls()
        s.layout += 1

    def _inside(self, pts: Iterable[tuple[float, float]], margin: float = 0.0) -> bool:
        s = self._state
        return all(
            x - margin >= -1e-6
            and x + margin <= s.width + 1e-6
            and y - margin >= -1e-6
            and y + margin <= s.height + 1e-6
            for x, y in pts
        )

    def _shape_inside(self, shape: ShapeSpec, x: float, y: float, heading: float) -> bool:
        if shape.kind == "circle":
            return self._inside([(x, y)], shape.radius_mm)
        return self._inside(shape.world_vertices(x, y, heading))

    def _check_new_shape(
        self, what: str, ident: str, shape: ShapeSpec, x: float, y: float, heading: float
    ) -> None:
        """An item may be added: its id is new and its shape stays inside the arena."""
        self._state.check_new_id(ident)
        if not self._shape_inside(shape, x, y, heading):
            raise EditError(f"{what} {ident} would stick out of the arena")

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
        s = self._state
        self._check_new_shape("obstacle", ident, shape, x, y, heading)
        body, shapes = bodies.obstacle(shape, x, y, heading)
        s.space.add(body, *shapes)
        overlapping = self._agents_touching(shapes)
        if overlapping:
            s.space.remove(body, *shapes)
            raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
        obstacle = Obstacle(ident, shape, x, y, heading, colour, body, shapes)
        s.obstacles[ident] = obstacle
        s.sensors.obstacles_changed()
        s.layout += 1
        return obstacle

    def _place_bodies(self) -> None:
        """On the discs drive, put the robots' and objects' bodies where they are (a query's need).

        Chipmunk is not stepped on that drive (common/sim2d/world_discs.py).
        """
        world_discs.place_bodies(self._state)

    def _agents_touching(self, shapes: list[pymunk.Shape]) -> list[str]:
        s = self._state
        self._place_bodies()
        found = []
        for shape in shapes:
            for info in s.space.shape_query(shape):
                body = info.shape.body if info.shape else None  # a shape in the space has one
                agent = s.agent_by_body.get(id_of(body)) if body is not None else None
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
        s = self._state
        self._check_new_shape("object", ident, shape, x, y, heading)
        if mass_g <= 0:
            raise EditError(f"object {ident}: mass must be positive")
        body, shapes = bodies.movable_object(shape, x, y, heading, mass_g)
        if self._blocked(shapes, CAT_OBSTACLE | CAT_ROBOT, body):
            raise EditError(f"object {ident} would overlap an obstacle or an agent")
        obj = MovableObject(ident, kind, shape, mass_g, friction, resistivity, colour, body, shapes)
        obj.floor_joints = bodies.floor_friction(s.space.static_body, body, mass_g, friction, shape)
        s.space.add(body, *shapes, *obj.floor_joints)
        s.objects.append(obj)
        s.object_by_body[id_of(body)] = obj
        self._sync_tongs()
        s.layout += 1
        return obj

    def _sync_tongs(self) -> None:
        """Tongs into the space, or out of it, as the objects they could touch come and go."""
        s = self._state
        wanted = s.drive == "joints" or bool(s.objects)
        if wanted == s.tongs_in:
            return
        tongs = [tong for agent in s.agents for tong in agent.tongs]
        if tongs:
            if wanted:
                s.space.add(*tongs)
            else:
                s.space.remove(*tongs)
        s.tongs_in = wanted

    def _blocked(self, shapes: list[pymunk.Shape], mask: int, body: pymunk.Body) -> bool:
        s = self._state
        self._place_bodies()
        for shape in shapes:
            shape.cache_bb()
            for info in s.space.shape_query(shape):
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
        s = self._state
        s.check_new_id(ident)
        if not self._inside([(x, y)]):
            raise EditError(f"light {ident} is outside the arena")
        if period_s <= 0 or radius_mm <= 0 or intensity < 0:
            raise EditError(f"light {ident}: period and radius must be positive, intensity >= 0")
        light = Light(ident, x, y, intensity, radius_mm, mode, period_s, colour)
        s.lights.append(light)
        s.layout += 1
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
        s = self._state
        self._check_new_shape("zone", ident, shape, x, y, heading)
        zone = Zone(ident, kind, shape, x, y, heading, colour)
        s.zones[ident] = zone
        s.layout += 1
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
        s = self._state
        s.check_new_id(ident)
        r = spec.radius_mm
        if not self._inside([(x, y)], r):
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would stick out of the arena")
        hits = s.space.point_query((x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE))
        if hits:
            raise EditError(f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle")
        s.serial += 1
        fitted = gripper and spec.gripper is not None
        agent = bodies.agent(
            ident,
            spec,
            s.serial,
            x,
            y,
            heading,
            fitted,
            joints=s.drive == "joints",
            tongs_mask=s.tongs_mask,
        )
        agent.colour = colour or spec.colour
        s.space.add(*agent.physics(tongs=s.tongs_in))
        s.agents.append(agent)
        s.agent_by_body[id_of(agent.body)] = agent
        arm = float(spec.gripper.arm_down) if spec.gripper else 0.0
        s.append_agent_rows((x, y, heading), arm)
        s.homes[ident] = (float(x), float(y), float(heading))
        if not defer_tables:
            s.rebuild_tables()
        s.layout += 1
        return agent

    def finish_agents(self) -> None:
        """Rebuild the per-agent tables after add_agent(..., defer_tables=True)."""
        s = self._state
        s.rebuild_tables()

    # -- generic edits ------------------------------------------------------------------

    def pose_of(self, ident: str) -> tuple[float, float, float]:
        s = self._state
        for slot, agent in enumerate(s.agents):
            if agent.id == ident:
                x, y, h = s.agent_pose[slot]
                return float(x), float(y), float(h)
        for obj in s.objects:
            if obj.id == ident and obj.body is not None:
                self._place_bodies()  # the discs drive moves objects in its arrays
                return obj.body.position.x, obj.body.position.y, obj.body.angle
        if ident in s.obstacles:
            o = s.obstacles[ident]
            return o.x, o.y, o.heading
        if ident in s.zones:
            z = s.zones[ident]
            return z.x, z.y, z.heading
        for light in s.lights:
            if light.id == ident:
                return light.x, light.y, 0.0
        raise EditError(f"no object named {ident!r} in this world")

    def shape_of(self, ident: str) -> ShapeSpec | None:
        s = self._state
        for agent in s.agents:
            if agent.id == ident:
                return ShapeSpec.circle(agent.spec.radius_mm)
        obj = s.find_object(ident)
        if obj is not None:
            return obj.shape
        if ident in s.obstacles:
            return s.obstacles[ident].shape
        if ident in s.zones:
            return s.zones[ident].shape
        return None  # lights are points

    def move(self, ident: str, x: float, y: float, heading: float | None = None) -> None:
        """Move (and optionally rotate) anything; validated, undone if it breaks a rule."""
        s = self._state
        old = self.pose_of(ident)  # an object's places the bodies first (discs drive)
        heading = old[2] if heading is None else heading
        shape = self.shape_of(ident)
        if shape is not None and not self._shape_inside(shape, x, y, heading):
            raise EditError(f"{ident} would stick out of the arena at ({x:.0f}, {y:.0f})")
        if shape is None and not self._inside([(x, y)]):
            raise EditError(f"{ident} would be outside the arena at ({x:.0f}, {y:.0f})")
        for light in s.lights:
            if light.id == ident:
                light.x, light.y = x, y
                s.layout += 1
                return
        if ident in s.zones:
            z = s.zones[ident]
            z.x, z.y, z.heading = x, y, heading
            s.layout += 1
            return
        if ident in s.obstacles:
            o = s.obstacles[ident]
            assert o.body is not None
            o.body.position, o.body.angle = (x, y), heading
            s.space.reindex_shapes_for_body(o.body)
            overlapping = self._agents_touching(o.shapes)
            if overlapping:
                o.body.position, o.body.angle = (o.x, o.y), o.heading
                s.space.reindex_shapes_for_body(o.body)
                raise EditError(f"obstacle {ident} would overlap agent(s) {', '.join(overlapping)}")
            o.x, o.y, o.heading = x, y, heading
            s.sensors.obstacles_changed()
            s.layout += 1
            return
        for slot, agent in enumerate(s.agents):
            if agent.id == ident:
                r = agent.spec.radius_mm
                hits = s.space.point_query((x, y), r - 0.5, pymunk.ShapeFilter(mask=CAT_OBSTACLE))
                if hits:
                    raise EditError(
                        f"agent {ident} at ({x:.0f}, {y:.0f}) would overlap an obstacle"
                    )
                for b in (agent.body, agent.control):
                    if b is None:
                        continue
                    b.position, b.angle = (x, y), heading
                    b.velocity, b.angular_velocity = (0, 0), 0.0
                s.space.reindex_shapes_for_body(agent.body)
                s.agent_pose[slot] = (x, y, heading)
                s.layout += 1
                return
        obj = s.find_object(ident)
        if obj is not None and obj.body is not None:
            if obj.held_by is not None:
                self._grippers.release(obj)
            old_pos, old_angle = obj.body.position, obj.body.angle
            obj.body.position, obj.body.angle = (x, y), heading
            s.space.reindex_shapes_for_body(obj.body)
            if self._blocked(obj.shapes, CAT_OBSTACLE, obj.body):
                obj.body.position, obj.body.angle = old_pos, old_angle
                s.space.reindex_shapes_for_body(obj.body)
                raise EditError(f"object {ident} would overlap an obstacle at ({x:.0f}, {y:.0f})")
            obj.body.velocity, obj.body.angular_velocity = (0, 0), 0.0
            s.layout += 1
            return
        raise EditError(f"no object named {ident!r} in this world")

    def set_home(self, ident: str) -> None:
        """Make an agent's current pose its start pose (a map editor placed it)."""
        s = self._state
        if ident in s.homes:
            s.homes[ident] = self.pose_of(ident)

    def reset_agent(self, ident: str) -> tuple[float, float, float]:
        """Put an agent back at its start pose, at rest; returns the pose."""
        s = self._state
        home = s.homes.get(ident)
        if home is None:
            raise EditError(f"no agent named {ident!r} in this world")
        self.move(ident, *home)
        return home

    def rotate(self, ident: str, heading: float) -> None:
        x, y, _ = self.pose_of(ident)
        self.move(ident, x, y, heading)

    def remove(self, ident: str) -> None:
        s = self._state
        if ident in s.obstacles:
            o = s.obstacles.pop(ident)
            assert o.body is not None  # set when it was added to this world
            s.space.remove(o.body, *o.shapes)
            s.sensors.obstacles_changed()
        elif ident in s.zones:
            del s.zones[ident]
        elif any(light.id == ident for light in s.lights):
            s.lights = [light for light in s.lights if light.id != ident]
        elif (obj := s.find_object(ident)) is not None:
            if obj.held_by is not None:
                self._grippers.release(obj)
            assert obj.body is not None  # set when it was added to this world
            s.space.remove(obj.body, *obj.shapes, *obj.floor_joints)
            s.objects.remove(obj)
            s.object_by_body.pop(id_of(obj.body), None)
            self._sync_tongs()
        else:
            try:
                slot = s.agent_slot(ident)
            except KeyError:
                raise EditError(f"no object named {ident!r} in this world") from None
            agent = s.agents[slot]
            if agent.held is not None:
                self._grippers.release(agent.held)
            s.space.remove(*agent.physics(tongs=s.tongs_in))
            del s.agents[slot]
            s.homes.pop(ident, None)
            s.agent_by_body.pop(id_of(agent.body), None)
            s.delete_agent_rows(slot)
            s.rebuild_tables()
        s.layout += 1
