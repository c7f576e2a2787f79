"""01 - Braitenberg obstacle avoidance: sensors wired straight to the wheels.

What it teaches: the smallest useful controller. Each do_work reads the 8 IR
proximity sensors and sets both wheel speeds from a weighted sum of them (a
Braitenberg vehicle, "fear": an obstacle on the left speeds up the left wheel,
so the robot turns away). No state, no planning: behaviour from wiring.

Suits: maps/foraging.json (`wart up`'s arena: a minute on any of its robots
without touching a wall, a rock or a robot) and maps/empty.json. In the maze's
narrow corridors it can meet a robot parked head-on and touch it.

    wart control --context arena --agent k1 examples/01_braitenberg.py
    wart deploy  --context arena --agent k1 examples/01_braitenberg.py
"""

from common.controller import Controller, Khepera

CRUISE = 6  # pulses per 10 ms, about 48 mm/s
# A front reading this high stops the robot. The gripper's tongs reach 27 mm past the
# front sensors: they touch a wall ahead while it reads about 130, and a robot seen
# between two sensors' beams while it reads far less.
NEAR = 45


class Braitenberg(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        s = robot.proximity().values  # 0..5 round the front, left to right; larger is closer
        left = 1.5 * s[0] + 3.0 * s[1] + 3.0 * s[2]
        right = 3.0 * s[3] + 3.0 * s[4] + 1.5 * s[5]
        turn = (left - right) / 10  # > 0: the obstacle is on the left, so turn right
        front = max(s[1], s[2], s[3], s[4])
        if front > NEAR / 3 and abs(left - right) < front:  # head-on: a symmetric view
            turn += 4 if left >= right else -4  # would cancel the turn, so pick a side
        base = CRUISE * (1 - front / NEAR)  # slower as it nears; backs off past NEAR
        robot.set_speeds(base + turn, base - turn)

    def cleanup(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)
