"""``wart control --context CTX --agent k1 my_controller.py``: drive a robot from this machine.

Logs in (--user; the password from --password-file, WART_PASSWORD or a
prompt), checks the file, joins the agent context, queues for the agent and
shows your position and estimated start while you wait. During your slot your
controller runs here and drives the robot over Zenoh; it stops at the end of
the slot, when the context's host stops it, or on Ctrl-C (which also cancels
a request still waiting). The same controller file runs unchanged against a
simulated robot and a real one, and uploaded with ``wart deploy``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from common import cli, keys
from common.client.agent_client import AgentClient
from common.client.lab_client import LabClient
from common.controller import load_controller
from common.controller.upload_gate import PrecheckError, precheck
from common.messages import OutputLines, RequestStatus
from common.zconfig import NetworkOptions
from services.commands.terminal import run_logged_in, say


def tool_parser(prog: str, doc: str) -> argparse.ArgumentParser:
    p = cli.parser(prog, doc)
    p.add_argument("controller", type=Path, help="your controller file (a .py file)")
    p.add_argument("--context", required=True, help="the agent context, e.g. arena")
    p.add_argument("--agent", required=True, help="the robot to drive, e.g. k1")
    p.add_argument("--user", required=True)
    p.add_argument("--password-file", help="read the password from this file")
    return p


def read_checked(path: Path) -> bytes:
    """The file's bytes if it passes the pre-run check; PrecheckError/OSError otherwise."""
    source = path.read_bytes()
    precheck(source, path.name)
    return source


def when(eta: float | None) -> str:
    if eta is None:
        return "unknown (no slot starts for now: remote control is off, or the arena is stopped)"
    wait = max(0.0, eta - time.time())
    return f"in about {wait:.0f} s (at {time.strftime('%H:%M:%S', time.localtime(eta))})"


def show_wait(position: int, eta: float | None) -> None:
    if position <= 1:
        say(f"you are next; your slot starts {when(eta)}")
    else:
        say(f"position {position} in the queue; your slot starts {when(eta)}")


def show_output(output: OutputLines) -> None:
    for line in output.lines:
        say(f"[{output.agent}] {line}")


def session_for(
    args: argparse.Namespace, options: NetworkOptions, body: Callable[[AgentClient], int]
) -> int:
    """Connect, log in, join the context and run ``body``; errors become clear messages."""
    try:
        keys.check_ident("context", args.context)
        if hasattr(args, "agent"):  # `wart record` names no robot
            keys.check_ident("agent", args.agent)
        keys.check_ident("user", args.user)
    except ValueError as exc:
        return cli.fail(str(exc))

    def joined(client: LabClient) -> int:
        return body(AgentClient(client, args.context).join())

    return run_logged_in(args, options, joined)


def interrupt_event() -> threading.Event:
    """An event set by Ctrl-C or SIGTERM (the tools then cancel cleanly)."""
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        say("stopping (Ctrl-C again to quit at once)...")
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return stop


def main(argv: Sequence[str] | None = None, prog: str = "wart control") -> int:
    p = tool_parser(prog, __doc__ or "")
    args, options = cli.parse_networked(p, argv)
    try:
        read_checked(args.controller)
        controller = load_controller(args.controller)
    except (PrecheckError, OSError) as exc:
        return cli.fail(str(exc))
    except Exception as exc:  # the student's module raised while loading: show it plainly
        return cli.fail(f"{args.controller.name} could not be loaded: {type(exc).__name__}: {exc}")
    stop = interrupt_event()

    def started(status: RequestStatus) -> None:
        left = (status.end or time.time()) - time.time()
        say(f"your slot on {status.agent} started: driving for {left:.0f} s")

    def body(agents: AgentClient) -> int:
        agents.on_output = show_output
        result = agents.drive(
            args.agent, controller, stop=stop, on_wait=show_wait, on_start=started
        )
        if result.error:
            say(result.error.rstrip())
        say(f"{result.status}: {result.reason} ({result.iterations} steps)")
        return 0 if result.status in ("finished", "interrupted") and not result.error else 1

    return session_for(args, options, body)


if __name__ == "__main__":
    sys.exit(main())
