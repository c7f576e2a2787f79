"""02 - Wall following: keep a wall on the left at a steady distance.

What it teaches: closing a loop on one measurement. The left sensors give a
distance-like reading; the error from a set point steers the robot (a
proportional controller), with two rules around it: turn right on the spot
when something is ahead, and curve left to find the wall again when it is lost.

Suits: maps/maze.json (long walls and corners).

    wart control --context arena --agent k1 examples/02_wall_following.py
"""

from common.controller import Controller, Khepera

TARGET = 300  # proximity reading to hold on the left (about 18 mm from the wall)
CRUISE = 8


class WallFollower(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        s = robot.proximity().values
        side = max(s[0], 0.8 * s[1])
        front = max(s[2], s[3], 0.8 * s[4])
        if front > 250:  # a corner or an obstacle ahead: turn right on the spot
            robot.set_speeds(6, -6)
        elif side < 40:  # no wall on the left: curve left to find one
            robot.set_speeds(3, CRUISE)
        else:
            error = (TARGET - side) / 60  # > 0: too far from the wall, steer left
            error = max(-5.0, min(5.0, error))
            robot.set_speeds(CRUISE - error, CRUISE + error)

    def cleanup(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)
