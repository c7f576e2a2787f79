"""The calibration dance: run it on a real robot, then `wart calibrate` fits the robot's twin.

Put the robot in the middle of the arena, facing a wall about 0.5 m away, and run
it (at most 40 s): it drives to the wall, turns slowly there so every IR sensor sees
it, then turns, arcs and stops so that each wheel's scale, the wheel base and the
command latency show. Then, with the run's recording (the arena's camera must see
the robot):

    wart deploy --context lab --agent k1 examples/calibration_dance.py
    wart record get RUN --context lab --user me
    wart calibrate k1 --recordings RUN.mcap

docs/CALIBRATION.md says what is fitted and its limits.
"""

from common.controller import Controller, Khepera
from common.controller.calibration import Dance


class CalibrationDance(Controller):
    """Drives the dance (common/controller/calibration.py) on the robot's clock, then stops."""

    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        self.start = robot.time()
        self.dance = Dance()

    def do_work(self, robot: Khepera) -> None:
        t = robot.time() - self.start
        robot.set_speeds(*self.dance.command(t, robot.proximity().values))
