"""The gripper turret of every agent that has one (thesis 6.8.3, the K-Team gripper).

An arm that moves between up and down at the type's rate, two fingers, and a
light barrier between the tongs (read by the sensing pass). Its rules:

- a raised arm passes over everything: its tongs, and what it holds, collide
  with nothing until the arm is lowered again;
- lowered tongs collide with everything, or with the velocity drive with movable
  objects only (World.tongs_mask, collision.TONGS_MASK_LIGHT: what a crowd costs);
- closing the fingers on a lowered arm grips the object whose centre lies in
  the barrier's box; the object then rides on the robot (a kinematic body
  carried every tick) until the fingers open or the object is moved or removed;
- the collision exception area: an object whose centre is between the open,
  lowered tongs does not collide with the robot, so it can be driven into the
  grip.

State per agent (arm, arm target, fingers) lives in the world's state
(common/sim2d/world_state.py) like every other per-agent value, as do how many
agents hold an object and the grip version, which sensing and the discs drive
read; this class holds the rules and what only it needs (whether an arm is
moving).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pymunk

from common.sim2d import world_discs
from common.sim2d.collision import (
    CAT_ALL,
    CAT_OBJECT,
    CAT_TONGS,
    COLL_OBJECT,
    COLL_ROBOT,
    COLL_TONGS,
)

if TYPE_CHECKING:
    from common.sim2d.entities import MovableObject
    from common.sim2d.world_state import WorldState

FINGERS_OPEN = 0
FINGERS_CLOSED = 1
HOLDING = 2  # gripper state: closed on an object


class GripperTurrets:
    """The grippers of one world's agents: arm, fingers, grip and carry."""

    def __init__(self, state: WorldState) -> None:
        self._state = state
        self.arms_moving = False  # set by set_arm; the arm update runs only while true
        # The collision exception area, for the robots' bodies and their tongs.
        exception = self.collision_exception
        state.space.on_collision(COLL_ROBOT, COLL_OBJECT, pre_solve=exception)
        state.space.on_collision(COLL_TONGS, COLL_OBJECT, pre_solve=exception)

    # -- commands ---------------------------------------------------------------------

    def set_arm(self, slot: int, position: int) -> bool:
        """Aim the arm; False if the agent has no gripper."""
        w = self._state
        g = w.agents[slot].spec.gripper
        if g is None or not w.agents[slot].has_gripper:
            return False
        w.arm_target[slot] = float(np.clip(position, g.arm_up, g.arm_down))
        self.arms_moving = True
        return True

    def set_grip(self, slot: int, closed: bool) -> bool:
        """Close (gripping what is between the tongs) or open; False without a gripper."""
        w = self._state
        agent = w.agents[slot]
        if not agent.has_gripper:
            return False
        w.fingers[slot] = FINGERS_CLOSED if closed else FINGERS_OPEN
        if closed and agent.held is None:
            obj = self.object_in_grip(slot)
            if obj is not None:
                self._grip(slot, obj)
        elif not closed and agent.held is not None:
            self.release(agent.held)
        return True

    # -- reading ----------------------------------------------------------------------

    def state(self, slot: int) -> int:
        """0 open, 1 closed, 2 holding."""
        if self._state.agents[slot].held is not None:
            return HOLDING
        return int(self._state.fingers[slot])

    def resistivity(self, slot: int) -> int:
        agent = self._state.agents[slot]
        g = agent.spec.gripper
        if agent.held is not None:
            return agent.held.resistivity
        return g.empty_resistivity if g else 0

    def object_in_grip(self, slot: int) -> MovableObject | None:
        """The free object whose centre is in the barrier's box of a lowered arm."""
        w = self._state
        g = w.agents[slot].spec.gripper
        if g is None or not w.arm_lowered(slot):
            return None
        best: MovableObject | None = None
        world_discs.place_bodies(w)  # the discs drive moves objects in its arrays, not bodies
        for obj in w.objects:
            if obj.held_by is not None or obj.body is None:
                continue
            lx, ly = self._robot_frame(slot, obj.body.position.x, obj.body.position.y)
            if (
                g.presence_x_mm[0] <= lx <= g.presence_x_mm[1]
                and abs(ly) <= g.presence_half_width_mm
            ):
                best = obj
        return best

    # -- grip and release ------------------------------------------------------------------

    def _robot_frame(self, slot: int, x: float, y: float) -> tuple[float, float]:
        ax, ay, th = self._state.agent_pose[slot]
        dx, dy = x - ax, y - ay
        c, s = math.cos(th), math.sin(th)
        return c * dx + s * dy, -s * dx + c * dy

    def _grip(self, slot: int, obj: MovableObject) -> None:
        w = self._state
        agent = w.agents[slot]
        assert obj.body is not None
        world_discs.place_bodies(w)
        w.grip_version += 1
        lx, ly = self._robot_frame(slot, obj.body.position.x, obj.body.position.y)
        obj.held_by = agent
        obj.held_offset = (lx, ly, obj.body.angle - w.agent_pose[slot, 2])
        agent.held = obj
        w.holders += 1
        w.space.remove(*obj.floor_joints)
        obj.body.body_type = pymunk.Body.KINEMATIC
        for s in obj.shapes:
            s.filter = pymunk.ShapeFilter(group=agent.serial, categories=CAT_OBJECT)

    def release(self, obj: MovableObject) -> None:
        """Put a held object back on the floor where it is, at rest."""
        agent = obj.held_by
        if agent is None or obj.body is None:
            return
        w = self._state
        world_discs.place_bodies(w)
        w.grip_version += 1
        obj.held_by = None
        agent.held = None
        w.holders -= 1
        obj.body.body_type = pymunk.Body.DYNAMIC
        obj.body.mass = obj.mass_g
        if obj.shape.kind == "circle":
            obj.body.moment = pymunk.moment_for_circle(obj.mass_g, 0, obj.shape.radius_mm)
        else:
            obj.body.moment = pymunk.moment_for_poly(obj.mass_g, obj.shape.vertices())
        obj.body.velocity, obj.body.angular_velocity = (0, 0), 0.0
        for s in obj.shapes:
            s.filter = pymunk.ShapeFilter(categories=CAT_OBJECT)
        w.space.add(*obj.floor_joints)

    def collision_exception(
        self, arbiter: pymunk.Arbiter, space: pymunk.Space, data: object
    ) -> None:
        """pymunk pre-solve: an object between the open, lowered tongs does not collide."""
        w = self._state
        robot_shape, object_shape = arbiter.shapes
        if robot_shape.body is None or object_shape.body is None:
            return
        agent = w.agent_of_body(robot_shape.body)
        if agent is None or not agent.has_gripper or agent.spec.gripper is None:
            return
        slot = w.slot_of(agent)
        if w.fingers[slot] != FINGERS_OPEN or not w.arm_lowered(slot):
            return
        g = agent.spec.gripper
        p = object_shape.body.position
        lx, ly = self._robot_frame(slot, p.x, p.y)
        if g.grip_x_mm[0] <= lx <= g.grip_x_mm[1] and abs(ly) <= g.gap_mm / 2:
            arbiter.process_collision = False

    # -- every tick ---------------------------------------------------------------------------

    def move_arms(self, dt: float) -> None:
        """Arms toward their targets; an arm that crosses 'lowered' changes what it hits."""
        w = self._state
        if not self.arms_moving:
            return
        if not len(w.agents) or not np.any(w.arm != w.arm_target):
            self.arms_moving = False
            return
        t = w.tables
        was_lowered = w.arm >= t.arm_lowered_above
        step = t.arm_rate * dt
        w.arm += np.clip(w.arm_target - w.arm, -step, step)
        now_lowered = w.arm >= t.arm_lowered_above
        for slot in np.nonzero(was_lowered != now_lowered)[0]:  # only arms that crossed
            agent = w.agents[int(slot)]
            lowered = bool(now_lowered[slot])
            mask = w.tongs_mask if lowered else 0  # a raised arm passes over everything
            for tong in agent.tongs:
                tong.filter = pymunk.ShapeFilter(
                    group=agent.serial, categories=CAT_TONGS, mask=mask
                )
            mask = CAT_ALL if lowered else 0
            if agent.held is not None:
                for s in agent.held.shapes:
                    s.filter = pymunk.ShapeFilter(
                        group=agent.serial, categories=CAT_OBJECT, mask=mask
                    )

    def carry(self) -> None:
        """Held objects follow their robots (pose and velocity)."""
        w = self._state
        if not w.holders:
            return
        for slot, agent in enumerate(w.agents):
            obj = agent.held
            if obj is None or obj.body is None:
                continue
            x, y, th = w.agent_pose[slot]
            lx, ly, lh = obj.held_offset
            c, s = math.cos(th), math.sin(th)
            obj.body.position = (x + c * lx - s * ly, y + s * lx + c * ly)
            obj.body.angle = th + lh
            vx, vy, wz = w.agent_vel[slot]
            obj.body.velocity = (vx - wz * (s * lx + c * ly), vy + wz * (c * lx - s * ly))
            obj.body.angular_velocity = wz
