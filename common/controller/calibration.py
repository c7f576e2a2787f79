"""The calibration dance: a timed drive that lets `wart calibrate` see every parameter.

Run on a real robot by examples/calibration_dance.py from the middle of a 1 m arena,
heading along +x, it drives toward the wall ahead until its front sensors see it close and
spins slowly in place so each IR sensor faces the wall, backs away, then turns both
ways, drives arcs and straight lines with stops between (the wheel base needs turns,
each wheel's scale the arcs, the latency the changes of command). About 40 s.
"""

from __future__ import annotations

from collections.abc import Sequence

# (seconds, left, right): speed units (a Khepera: 8 mm/s a unit). First toward the wall
# ahead, each step until its time is up or the front sensors read ``until`` (the robot's
# own drift must not make it miss the wall); then a timed tail of turns, arcs and stops.
NEAR: tuple[tuple[float, int, int, int], ...] = (  # (seconds, left, right, until)
    (0.5, 0, 0, 0),
    (8.0, 10, 10, 120),  # toward the wall ahead, to about 30 mm from it
    (4.0, 3, 3, 500),  # slowly, to about 15 mm
    (6.9, -3, 3, 0),  # one slow turn on the spot: every sensor faces the wall
    (0.5, 0, 0, 0),
    (4.0, -10, -10, 0),  # back away, toward the middle again
)
TAIL: tuple[tuple[float, int, int], ...] = (
    (1.5, -6, 6),  # turn left
    (2.0, 12, 6),  # an arc to the right
    (0.5, 0, 0),
    (1.5, 6, -6),  # turn right
    (2.0, 6, 12),  # an arc to the left
    (1.0, 15, 15),  # straight, fast
    (0.5, 0, 0),
    (2.0, -6, 6),
    (1.5, 10, 10),
    (2.0, 8, 14),
    (1.0, 0, 0),
)
DANCE_MAX_S = sum(step[0] for step in NEAR) + sum(step[0] for step in TAIL)


class Dance:
    """Where the dance is: ``command`` gives the wheels' command at time ``t`` (seconds
    since it began) from the IR readings then; (0, 0) once it is over (``over``)."""

    def __init__(self) -> None:
        self.step = 0
        self.began = 0.0  # when the current step began
        self.over = False

    def command(self, t: float, proximity: Sequence[int]) -> tuple[int, int]:
        steps = [(sec, left, right, until) for sec, left, right, until in NEAR]
        steps += [(sec, left, right, 0) for sec, left, right in TAIL]
        front = max(proximity[2], proximity[3]) if len(proximity) >= 4 else 0
        while self.step < len(steps):
            seconds, left, right, until = steps[self.step]
            if t - self.began < seconds and not (until and front >= until):
                return left, right
            self.step += 1
            self.began = t
        self.over = True
        return 0, 0
