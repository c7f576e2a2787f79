"""A robot reset at any point of a poll round never makes the bridge's pose jump.

A scripted robot (the real protocol's requests and reply decoders, no port)
drives straight, 10 pulses per wheel per round. At one chosen request of one
round it reboots: its counters restart at zero and the link reports the reset
banner before answering, as SerialKheperaLink does. Whatever the position, the pose
must equal the travel that the counter reads showed, and never go backwards.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from typing import Any

import pytest

from services.bridge import protocol as P
from services.bridge.robot import KheperaRobot, RobotOptions

STEP = 10  # pulses per wheel per round
MM_PER_PULSE = 0.08


def _request_name(req: P.Request[Any]) -> str:
    return (
        req.letter if req.letter != "T" else f"T{req.fields[1]}{''.join(map(str, req.fields[2:]))}"
    )


class ScriptedRobot:
    """Answers requests like a Khepera with a gripper, and reboots when told to."""

    def __init__(self, reset_at: tuple[int, str] | None, on_banner: Callable[[str], None]) -> None:
        self.reset_at = reset_at  # (round, request name): reboot just before answering it
        self.on_banner = on_banner
        self.counters = 0
        self.round = -1
        self.seen_pulses = 0  # travel visible to anyone reading H: the truth the pose must match
        self._last_h: int | None = None
        self.closed = False
        self.done = threading.Event()

    def request(self, req: P.Request[Any]) -> Any:
        name = _request_name(req)
        if name == "N":  # the first read of a round: the robot has moved since the last one
            self.round += 1
            if self.round < 12:
                self.counters += STEP
            elif self.round >= 14:  # two rounds standing still: every read has been taken in
                self.done.set()
        if self.reset_at == (self.round, name):
            self.counters, self._last_h, self.reset_at = 0, None, None
            self.on_banner("BIOS version 5.02")
        values: tuple[object, ...]
        if name == "B":
            values = ("5.02", "1.00")
        elif name in ("N", "O"):
            values = (100,) * 8
        elif name == "H":
            if self._last_h is not None:
                self.seen_pulses += self.counters - self._last_h
            self._last_h = self.counters
            values = (self.counters, self.counters)
        elif name == "E":
            values = (1, 1)
        elif name.startswith("T"):
            values = () if name in ("TD", "TE") else (("1", "0") if name == "TB" else (200,))
        else:
            values = ()
        line = ",".join([req.reply_letter, *req.reply_prefix, *(str(v) for v in values)])
        return req.parse(line)

    def close(self) -> None:
        self.closed = True


ROUND = ["N", "O", "H", "E", "TH1", "TH0", "TG", "TF"]  # the order of a gripper round


@pytest.mark.parametrize("position", ROUND)
def test_reset_at_any_request_of_a_round_keeps_the_pose_right(position: str) -> None:
    robots: list[ScriptedRobot] = []

    def link_factory(port: str, baud: int, options: Any, on_banner: Callable[[str], None]) -> Any:
        robots.append(ScriptedRobot((4, position), on_banner))  # round 4 reads the gripper
        return robots[-1]

    options = RobotOptions(
        poll_interval=0, gripper=True, gripper_every=4, mm_per_pulse=MM_PER_PULSE
    )
    xs: list[float] = []
    robot = KheperaRobot("scripted", options, link_factory=link_factory)
    robot.add_listener(lambda s: xs.append(s.pose.x))
    with robot:
        assert robot.wait_online(2)
        assert robots[0].done.wait(5), "the robot was not polled for 12 rounds"
        truth = robots[0].seen_pulses * MM_PER_PULSE
        final = robot.state().pose.x
    assert robots[0].reset_at is None, "the reset was not injected"
    # 12 rounds of travel, counted from the connection's own H read; the step between
    # the reset and the next H read is seen by no one: one step lost, no more
    assert truth == pytest.approx(11 * STEP * MM_PER_PULSE)
    assert final == pytest.approx(truth)
    assert all(b >= a - 1e-9 for a, b in itertools.pairwise(xs)), "the pose went backwards"
    assert robot.state().pose.y == pytest.approx(0.0)
