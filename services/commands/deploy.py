"""``wart deploy --context CTX --agent k1 my_controller.py``: run your controller in the lab.

Uploads the file (checked here and again by the lab: at most 64 KiB of UTF-8
Python with a Controller subclass), queues it for the agent, shows your
position and estimated start, then the controller's output (prints,
exceptions) live while the lab's runner runs it in a sandbox for one slot.
Exits when the slot ends. Ctrl-C cancels the request (waiting or running).

``--dry-run`` queues nothing: the lab runs the file for a few simulated
seconds (``--seconds``, default 5) in a private copy of the arena, headless
and faster than real time, in the same sandbox, and says "will run" or "will
NOT run: ..." (an exception and its line, a collision with a wall, an
obstacle or another robot, no answer in time), with the wheel commands that
were at top speed. Exit status 0 for "will run", 1 otherwise.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

from common import cli
from common.agent_client import FINAL, AgentClient
from common.messages import DryRunReport, RequestStatus
from common.precheck import PrecheckError
from services.commands.control import (
    interrupt_event,
    read_checked,
    session_for,
    show_output,
    show_wait,
    tool_parser,
)
from services.commands.terminal import say

GONE_AFTER_S = 10.0  # the request missing from every queue state for this long: lost


def show_report(report: DryRunReport) -> None:
    say(
        f"dry run: {report.sim_seconds:g} simulated s in {report.wall_seconds:.1f} s, "
        f"{report.steps} steps"
    )
    for hit in report.collisions[:10]:
        named = f"{hit.what} {hit.ident}" if hit.ident else hit.what
        say(f"  collision at {hit.at:.2f} s: {named}")
    if report.commands:
        say(f"  {report.saturated} of {report.commands} wheel commands at top speed")
    for line in report.output[:20]:
        say(f"  | {line}")
    say(report.verdict)


def main(argv: Sequence[str] | None = None, prog: str = "wart deploy") -> int:
    p = tool_parser(prog, __doc__ or "")
    p.add_argument(
        "--dry-run",
        action="store_true",
        help="queue nothing: run it a few simulated seconds in a private copy of the arena",
    )
    p.add_argument(
        "--seconds", type=float, default=5.0, help="simulated seconds of a dry run (0-30)"
    )
    args, options = cli.parse(p, argv)
    assert options is not None
    if not 0 < args.seconds <= 30:
        return cli.fail("--seconds must be more than 0 and at most 30")
    try:
        source = read_checked(args.controller)
    except (PrecheckError, OSError) as exc:
        return cli.fail(str(exc))
    if args.dry_run:

        def dry(agents: AgentClient) -> int:
            say(f"dry run of {args.controller.name} on {args.agent} ({args.seconds:g} s)...")
            report = agents.dry_run(
                args.agent, source, filename=args.controller.name, seconds=args.seconds
            )
            show_report(report)
            return 0 if report.will_run else 1

        return session_for(args, options, dry)
    stop = interrupt_event()

    def body(agents: AgentClient) -> int:
        agents.on_output = lambda o: show_output(o) if o.request_id == rid[0] else None
        rid: list[str] = [""]
        queued = agents.queue(args.agent, "deploy", source=source, filename=args.controller.name)
        rid[0] = queued.request_id
        say(f"uploaded {args.controller.name} as request {queued.request_id}")
        show_wait(queued.position, queued.start_eta)
        shown: tuple[int, float | None] | None = None
        running = False
        final: RequestStatus | None = None
        missing_since: float | None = None
        while final is None:
            # Once running, only the end matters: waiting for "running" again would
            # return at once, every time, and spin a core.
            wanted = FINAL if running else FINAL | {"running"}
            status = agents.wait_status(rid[0], wanted, timeout=0.5, stop=stop)
            if stop.is_set():
                agents.cancel_quietly(rid[0])
                final = agents.wait_status(rid[0], FINAL, timeout=5.0)
                say(f"cancelled: {final.reason if final else 'request withdrawn'}")
                return 0
            if status is not None and status.status in FINAL:
                final = status
                break
            if status is not None and not running:
                running = True
                left = (status.end or 0) - status.start if status.start else 0
                say(f"running on {args.agent} for {left:.0f} s; output follows")
                continue
            where = agents.position(rid[0])
            if where is None and agents.latest_state is not None:
                # The arena's queues no longer hold the request (it restarted without
                # them, or ended it while we were away): say so rather than wait forever.
                missing_since = missing_since or time.monotonic()
                if time.monotonic() - missing_since > GONE_AFTER_S:
                    say(f"request {rid[0]} is no longer in {args.context}'s queues: it was lost")
                    return 1
            else:
                missing_since = None
            if not running and where is not None and where != shown and where[0] > 0:
                shown = where
                show_wait(*where)
        say(f"{final.status}: {final.reason}")
        return 0 if final.status == "finished" else 1

    return session_for(args, options, body)


if __name__ == "__main__":
    sys.exit(main())
