"""01 - Braitenberg obstacle avoidance: sensors wired straight to the wheels.

What it teaches: the smallest useful controller. Each do_work reads the 8 IR
proximity sensors and sets both wheel speeds from a weighted sum of them (a
Braitenberg vehicle, "fear": an obstacle on the left speeds up the left wheel,
so the robot turns away). No state, no planning: behaviour from wiring.

Suits: maps/maze.json (walls to avoid) and maps/empty.json (arena walls only).

    wart control --context arena --agent k1 examples/01_braitenberg.py
    wart deploy  --context arena --agent k1 examples/01_braitenberg.py
"""

from common.controller import Controller, Khepera

CRUISE = 10  # pulses per 10 ms, about 80 mm/s


class Braitenberg(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        s = robot.proximity().values  # 0..5 round the front, left to right; larger is closer
        left = 0.5 * s[0] + 1.0 * s[1] + 1.5 * s[2]
        right = 1.5 * s[3] + 1.0 * s[4] + 0.5 * s[5]
        turn = (left - right) / 100  # > 0: the obstacle is on the left, so turn right
        front = max(s[2], s[3])
        if front > 300:  # head-on: a symmetric wall would cancel the turn, so pick a side
            turn += 6 if left >= right else -6
        base = max(-3.0, CRUISE - front / 80)
        robot.set_speeds(base + turn, base - turn)

    def cleanup(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)
