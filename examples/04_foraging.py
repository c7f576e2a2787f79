"""04 - Gripper foraging: find a ball, grip it, carry it to the nest, drop it, repeat.

What it teaches: a controller with state (a finite-state machine) and the
gripper turret. SEARCH wanders with the arm down and the fingers open until
the barrier between the fingers sees an object; GRIP closes the fingers and
raises the arm; HOME follows the nest's lamp (phototaxis, example 03) while
avoiding obstacles; DROP lowers the arm and opens the fingers under the lamp;
LEAVE backs away and turns round before searching again.

Suits: maps/foraging.json (balls scattered east of a lit nest; use k0).

    wart deploy --context arena --agent k0 examples/04_foraging.py
"""

from common.controller import Controller, Khepera

CRUISE = 10
IN_NEST = 170  # ambient reading this bright: we are inside the nest, under its lamp


class Forager(Controller):
    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        self.state = "SEARCH"
        self.steps = 0  # steps spent in the current state
        self.carried = 0
        robot.arm_down()
        robot.open_gripper()

    def go(self, state: str) -> None:
        print(f"{self.state} -> {state}")
        self.state, self.steps = state, 0

    def avoid(self, robot: Khepera, base: float, steer: float = 0.0, fear: float = 700) -> None:
        s = robot.proximity().values
        left = 0.5 * s[0] + s[1] + 1.5 * s[2]
        right = 1.5 * s[3] + s[4] + 0.5 * s[5]
        front = max(s[2], s[3])
        turn = (left - right) / 100 - steer
        if front > fear:  # only walls and robots come this close outside the fingers
            turn += 6 if left >= right else -6
            base = -2
        robot.set_speeds(base + turn, base - turn)

    def do_work(self, robot: Khepera) -> None:
        self.steps += 1
        if self.state == "SEARCH":
            if robot.object_present():
                robot.set_speeds(0, 0)
                robot.close_gripper()
                self.go("GRIP")
            else:
                self.avoid(robot, CRUISE, fear=850)
        elif self.state == "GRIP":
            if self.steps == 5:
                robot.arm_up()
            if self.steps >= 15:
                self.go("HOME")
        elif self.state == "HOME":
            a = robot.ambient().values
            if min(a) < IN_NEST:
                robot.set_speeds(0, 0)
                robot.arm_down()
                self.go("DROP")
                return
            light_left = 500 - min(a[0], a[1], a[2])
            light_right = 500 - min(a[3], a[4], a[5])
            light_back = 500 - min(a[6], a[7])
            if light_back > max(light_left, light_right):
                robot.set_speeds(6, -6)
                return
            steer = max(-6.0, min(6.0, (light_left - light_right) / 30))
            self.avoid(robot, CRUISE, steer, fear=300)
        elif self.state == "DROP":
            if self.steps == 10:
                robot.open_gripper()
            if self.steps >= 15:
                self.carried += 1
                print(f"ball {self.carried} delivered")
                self.go("LEAVE")
        elif self.state == "LEAVE":
            if self.steps < 20:
                robot.set_speeds(-8, -8)
            elif self.steps < 45:
                robot.set_speeds(8, -8)
            else:
                self.go("SEARCH")

    def cleanup(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)
