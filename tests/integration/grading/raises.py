from common.controller import Controller, Khepera


class Raises(Controller):
    """Raises on its third step (grading tests: an exception with its line)."""

    period = 0.05
    steps = 0

    def do_work(self, robot: Khepera) -> None:
        self.steps += 1
        if self.steps == 3:
            raise ZeroDivisionError("division by zero on purpose")
        robot.set_speeds(5, 5)
