"""``wart arena takeover`` / ``handback``: a teacher drives a student's running robot.

    wart arena takeover ROBOT --user NAME --context CTX [--controller FILE] [--reason WHY]
    wart arena handback ROBOT --user NAME --context CTX

``takeover`` (the context's managers: its owner, or ``kick`` there) pauses
the student's controller running on ROBOT and holds the robot for this
session: still (speeds 0) or driven by the teacher's own ``--controller``
run on this machine. It hands the robot back when it ends: Ctrl-C, the
controller's end, or the student's slot's end; another manager may hand it
back first (``handback``). The take-over lives with this session: the tool
stays in the foreground while it holds the robot.
"""

from __future__ import annotations

import argparse
import threading
import time
from pathlib import Path

from common.client.agent_client import AgentClient
from common.controller import Controller, Khepera, load_controller
from common.lab_errors import LabError
from services.commands.terminal import say


class HoldStill(Controller):
    """A take-over without a controller: the robot stays where it is."""

    period = 0.1

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)


def add_takeover_parsers(sub: argparse._SubParsersAction) -> list[argparse.ArgumentParser]:
    s_take = sub.add_parser("takeover", help="pause a student's controller and drive its robot")
    s_take.add_argument("robot", help="the robot (agent) to take over, e.g. k1")
    s_take.add_argument("--controller", type=Path, help="drive with this controller (a .py file)")
    s_take.add_argument("--reason", default="", help="told to the student")
    s_back = sub.add_parser("handback", help="give a taken-over robot back to its student")
    s_back.add_argument("robot")
    return [s_take, s_back]


def run_takeover(agents: AgentClient, args: argparse.Namespace, stop: threading.Event) -> int:
    """The ``takeover`` / ``handback`` verbs over a joined AgentClient."""
    if args.verb == "handback":
        say(agents.hand_back(args.robot))
        return 0
    controller: Controller = HoldStill()
    if args.controller is not None:
        try:
            controller = load_controller(args.controller)
        except Exception as exc:  # the teacher's module raised while loading: say it plainly
            raise LabError(f"{args.controller}: {type(exc).__name__}: {exc}") from None
    taken = agents.take_over(args.robot, args.reason)
    until = time.strftime("%H:%M:%S", time.localtime(taken.end))
    how = f"driving it with {args.controller.name}" if args.controller else "holding it still"
    say(
        f"{args.robot} taken over from {taken.user} ({taken.request_id}): their controller "
        f"is paused; {how} until Ctrl-C or their slot's end at {until}"
    )
    try:
        steps = agents.drive_taken(taken, controller, stop)
    finally:
        if agents.is_taken_by(args.robot, agents.client.user):
            say(agents.hand_back(args.robot))
        else:
            say(f"{args.robot} is no longer taken over by you (handed back, or the run ended)")
    say(f"{steps} steps driven")
    return 0
