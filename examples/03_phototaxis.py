"""03 - Phototaxis: find a light and go to it.

What it teaches: choosing between behaviours by what the sensors say. The
ambient sensors read about 500 in the dark and less the brighter the light
on them. In the dark the robot explores (driving ahead, avoiding obstacles
like example 01); once a sensor sees light it steers towards the brighter
side, and it stops with its LEDs on when it is right under the lamp.

Suits: maps/phototaxis.json (a lamp behind a screen; k0 finds it from its start).

    wart deploy --context arena --agent k0 examples/03_phototaxis.py
"""

from common.controller import Controller, Khepera

DARK = 470  # above this on every sensor: no light in sight
ARRIVED = 120  # this bright: we are under the lamp
CRUISE = 10


class Phototaxis(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        a = robot.ambient().values  # smaller is brighter
        s = robot.proximity().values
        brightest = min(a)
        if brightest < ARRIVED:
            robot.set_speeds(0, 0)
            robot.set_leds(True, True)
            return
        left = 0.5 * s[0] + s[1] + 1.5 * s[2]
        right = 1.5 * s[3] + s[4] + 0.5 * s[5]
        avoid = (left - right) / 100
        if brightest > DARK:  # explore
            base, steer = CRUISE - max(s[2], s[3]) / 80, 0.0
        else:
            light_left = 500 - min(a[0], a[1], a[2])
            light_right = 500 - min(a[3], a[4], a[5])
            light_back = 500 - min(a[6], a[7])
            if light_back > max(light_left, light_right):  # the light is behind: turn round
                robot.set_speeds(6, -6)
                return
            steer = max(-6.0, min(6.0, (light_left - light_right) / 30))  # > 0: light on the left
            base = CRUISE - max(s[2], s[3]) / 80
        turn = avoid - steer
        robot.set_speeds(base + turn, base - turn)
        robot.set_leds(brightest <= DARK, False)

    def cleanup(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)
