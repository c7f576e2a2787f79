from common.controller import Controller, Khepera


class Talker(Controller):
    """Drives ahead and prints what it sees (tests the output relay)."""

    period = 0.1

    def initialize(self, robot: Khepera) -> None:
        print("hello from the sandbox")

    def do_work(self, robot: Khepera) -> None:
        print("front", robot.proximity().values[2], "t", round(robot.time(), 2))
        robot.set_speeds(12, 12)
