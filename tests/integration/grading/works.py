from common.controller import Controller, Khepera


class Works(Controller):
    """Drives straight ahead into the goal zone (grading tests)."""

    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(20, 20)
