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
# What a lowered gripper's tongs collide with under the velocity drive (World(drive=
# "velocity"), the swarm option): movable objects only, so they still push, and close
# on, balls and boxes; never robots, other robots' tongs or obstacles. In a crowd robots
# kept touching each other's tongs: half of chipmunk's step at 10,000 robots
# (docs/BENCHMARKS.md). No sensor sees tongs (IR rays hit the robots' discs),
# and tongs that hit walls held a robot 25 mm short of a wall head-on, where its front
# IR reads too little for the examples' rules to turn, and wedged it in corners. With
# the joints drive (the default) tongs collide with everything, as before.
TONGS_MASK_LIGHT = CAT_OBJECT
COLL_ROBOT = 1
COLL_TONGS = 2
COLL_OBJECT = 3
