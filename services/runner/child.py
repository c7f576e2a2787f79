"""The program that runs inside the sandbox: loads one uploaded controller and runs it.

Standard library only (the sandbox offers Debian's python3 and nothing else).
It has no Zenoh session, no keys and no lease: the trusted parent relays
robot state on stdin and reads commands from the file descriptor given as
its first argument, one JSON object per line each way. The student's prints
and tracebacks go to stdout/stderr, which the parent shows as the
controller's output.

    python3 -I -S child.py CMD_FD CONTROLLER_FILE [lockstep]

``lockstep`` (a dry run): no clock of its own. Each state the parent sends
is one tick of a private simulated world; the controller's ``do_work`` runs
whenever the state's simulated time reaches its next period, and every state
is answered with ``{"t": "step"}`` after the commands it caused, so the parent
steps its world as fast as the controller answers.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import traceback
from typing import Any


def main() -> int:
    cmd_fd = int(sys.argv[1])
    path = sys.argv[2]
    lockstep = sys.argv[3:] == ["lockstep"]
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "lib"))
    from common.controller import (
        ControllerLoop,
        Khepera,
        KheperaState,
        RobotCommand,
        load_controller,
    )

    out = os.fdopen(cmd_fd, "w", buffering=1)
    out_lock = threading.Lock()

    def tell(message: dict[str, Any]) -> None:
        with out_lock:
            out.write(json.dumps(message, separators=(",", ":")) + "\n")

    class PipeLink:
        def __init__(self) -> None:
            self.state = KheperaState()
            self.lock = threading.Lock()

        def latest(self) -> KheperaState:
            with self.lock:
                return self.state

        def send(self, command: RobotCommand) -> None:
            tell({"t": "cmd", **command.to_dict()})

    link = PipeLink()
    if lockstep:
        return run_lockstep(path, link, tell)
    stop = threading.Event()
    have_state = threading.Event()

    def read_parent() -> None:
        for line in sys.stdin:
            try:
                message = json.loads(line)
                if message.get("t") == "stop":
                    break
                if message.get("t") == "state":
                    state = KheperaState.from_dict(message)
                    with link.lock:
                        link.state = state
                    have_state.set()
            except (ValueError, TypeError, KeyError) as exc:
                print(f"[sandbox] ignored a bad state line: {exc}", file=sys.stderr)
        stop.set()

    threading.Thread(target=read_parent, daemon=True).start()

    try:
        controller = load_controller(path)
    except BaseException:
        tell({"t": "error", "message": traceback.format_exc(limit=5)})
        return 3

    tell({"t": "ready", "controller": type(controller).__name__})
    have_state.wait(5.0)
    loop = ControllerLoop(controller, Khepera(link), stop=stop)
    try:
        loop.run()
    except BaseException:
        traceback.print_exc()
        tell({"t": "error", "message": traceback.format_exc(limit=5)})
        return 4
    tell({"t": "done", "iterations": loop.iterations})
    return 0


def run_lockstep(path: str, link: Any, tell: Any) -> int:
    """Step the controller once per state read, on the states' simulated clock."""
    from common.controller import Khepera, KheperaState, load_controller

    try:
        controller = load_controller(path)
        period = float(controller.period)
        if not 0.001 <= period <= 10.0:
            raise ValueError(f"period {period} s is outside 0.001..10 s")
    except BaseException:
        tell({"t": "error", "message": traceback.format_exc(limit=5)})
        return 3
    tell({"t": "ready", "controller": type(controller).__name__})
    robot = Khepera(link)
    next_tick: float | None = None
    steps = 0
    try:
        for line in sys.stdin:
            message = json.loads(line)
            if message.get("t") == "stop":
                break
            if message.get("t") != "state":
                continue
            link.state = KheperaState.from_dict(message)
            now = link.state.time
            if next_tick is None:
                controller.initialize(robot)
                next_tick = now
            if now + 1e-9 >= next_tick:
                controller.do_work(robot)
                steps += 1
                next_tick += period
                if next_tick <= now:  # a period shorter than a tick: once per tick
                    next_tick = now + period
            tell({"t": "step", "n": steps})
        controller.cleanup(robot)
    except BaseException:
        tell({"t": "error", "message": traceback.format_exc(limit=5)})
        return 4
    tell({"t": "done", "iterations": steps})
    return 0


if __name__ == "__main__":
    sys.exit(main())
