"""Collision categories (pymunk shape filter bits) and collision types of a Sim2D world.

Obstacles, robots, movable objects and the gripper's tongs each have a category;
the gripper turret changes its tongs' and its held object's masks as the arm
moves, so both the world and the turret name them from here.
"""

from __future__ import annotations

CAT_OBSTACLE = 0b0001
CAT_ROBOT = 0b0010
CAT_OBJECT = 0b0100
CAT_TONGS = 0b1000
CAT_ALL = 0xFFFFFFFF
COLL_ROBOT = 1
COLL_TONGS = 2
COLL_OBJECT = 3
