from common.controller import Controller, Khepera


class Forward(Controller):
    """Drives straight ahead (tests)."""

    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(12, 12)
