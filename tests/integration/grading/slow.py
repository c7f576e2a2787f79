import time

from common.controller import Controller, Khepera


class Slow(Controller):
    """Works, slowly in wall-clock time (a runner can be killed while it runs)."""

    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        time.sleep(0.02)
        robot.set_speeds(20, 20)
