"""``wart deploy --context CTX --agent k1 my_controller.py``: run your controller in the lab.

Uploads the file (checked here and again by the lab: at most 64 KiB of UTF-8
Python with a Controller subclass), queues it for the agent, shows your
position and estimated start, then the controller's output (prints,
exceptions) live while the lab's runner runs it in a sandbox for one slot.
Exits when the slot ends, with how it ended. Ctrl-C cancels the request
(waiting or running). Should the end's news not arrive, it asks the arena.

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
from common.client.agent_client import FINAL, AgentClient
from common.controller.upload_gate import PrecheckError
from common.lab_errors import LabError
from common.messages import DryRunReport, RequestStatus, RequestStatusReply
from services.commands.control import (
    interrupt_event,
    read_checked,
    session_for,
    show_output,
    show_wait,
    tool_parser,
)
from services.commands.terminal import say

# The context tells a request's end once, as an event; a missed one is asked for
# (ctx/<ctx>/status) rather than guessed from the queues:
ASK_EVERY_S = 2.0  # while the request is missing from the queues or its slot overran
SILENT_AFTER_S = 10.0  # nothing heard from the context this long: ask how it stands
SLOT_END_GRACE_S = 3.0  # the end of a running slot not heard this long after it: ask
CONTEXT_DOWN_GIVE_UP_S = 60.0  # the context not answering this long: stop waiting


def show_report(report: DryRunReport) -> None:
    say(
        f"dry run: {report.sim_seconds:g} simulated s in {report.wall_seconds:.1f} s, "
        f"{report.steps} steps" + (f", {report.model}" if report.model else "")
    )
    for hit in report.collisions[:10]:
        named = f"{hit.what} {hit.ident}" if hit.ident else hit.what
        say(f"  collision at {hit.at:.2f} s: {named}")
    if report.commands:
        say(f"  {report.saturated} of {report.commands} wheel commands at top speed")
    for line in report.output[:20]:
        say(f"  | {line}")
    say(report.verdict)


class Follow:
    """What ``wart deploy`` knows of its request beyond the events, and when to ask.

    The events can be missed (a late subscription, a router or link blip); the
    queue states only show that a request left. So whenever the request is
    missing from the queues, its slot has run past its end, or the context has
    been silent a while, the context is asked. Its answer is the truth; no
    answer means the context is down, which is said as such.
    """

    def __init__(self, agents: AgentClient, request_id: str) -> None:
        self.agents = agents
        self.request_id = request_id
        self.slot_end: float | None = None  # wall-clock s, once running
        self.asked_at = float("-inf")  # monotonic
        self.down_since: float | None = None  # monotonic: the context not answering

    def due(self, running: bool) -> bool:
        now = time.monotonic()
        missing = (
            self.agents.latest_state is not None and self.agents.position(self.request_id) is None
        )
        overran = (
            running
            and self.slot_end is not None
            and time.time() > (self.slot_end + SLOT_END_GRACE_S)
        )
        if missing or overran or self.down_since is not None:
            return now - self.asked_at >= ASK_EVERY_S
        return now - max(self.agents.last_heard, self.asked_at) >= SILENT_AFTER_S

    def ask(self, ctx: str) -> RequestStatusReply | None:
        """The context's answer (None: no answer; said once, and when it is back)."""
        self.asked_at = time.monotonic()
        try:
            reply = self.agents.request_status(self.request_id)
        except LabError as exc:
            say(f"could not ask {ctx} about request {self.request_id}: {exc}")
            return None
        if reply is None:
            if self.down_since is None:
                self.down_since = self.asked_at
                say(f"the arena {ctx} is not answering (stopped or restarting?): waiting for it")
            return None
        if self.down_since is not None:
            self.down_since = None
            say(f"the arena {ctx} answers again")
        return reply

    def down_too_long(self) -> bool:
        return (
            self.down_since is not None
            and time.monotonic() - self.down_since > CONTEXT_DOWN_GIVE_UP_S
        )


def lost_message(ctx: str, request_id: str) -> str:
    return (
        f"the arena {ctx} has no record of request {request_id}: it was lost (most likely "
        "the arena restarted and could not keep it). Nothing of yours is running there; "
        "deploy the file again."
    )


def down_message(ctx: str, request_id: str) -> str:
    return (
        f"the arena {ctx} has not answered for {CONTEXT_DOWN_GIVE_UP_S:.0f} s: it is down, "
        f"so what became of request {request_id} cannot be known now; run `wart deploy` "
        "again once the arena is back"
    )


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
    args, options = cli.parse_networked(p, argv)
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

        def on_status(status: RequestStatus) -> None:
            if status.takeover and status.request_id == rid[0]:
                say(status.reason)  # a teacher's take-over and hand-back, in words

        agents.on_status = on_status
        rid: list[str] = [""]
        queued = agents.queue(args.agent, "deploy", source=source, filename=args.controller.name)
        rid[0] = queued.request_id
        say(f"uploaded {args.controller.name} as request {queued.request_id}")
        show_wait(queued.position, queued.start_eta)
        shown: tuple[int, float | None] | None = None
        running = False
        final: RequestStatus | None = None
        follow = Follow(agents, rid[0])
        while final is None:
            since = None  # the context's clock, when the slot's time left is counted from
            # Once running, only the end matters: waiting for "running" again would
            # return at once, every time, and spin a core.
            wanted = FINAL if running else FINAL | {"running"}
            status = agents.wait_status(rid[0], wanted, timeout=0.5, stop=stop)
            if stop.is_set():
                agents.cancel_quietly(rid[0])
                final = agents.wait_status(rid[0], FINAL, timeout=5.0)
                if final is None and follow.ask(args.context) is not None:
                    final = agents.wait_status(rid[0], FINAL, timeout=0)
                say(f"cancelled: {final.reason if final else 'request withdrawn'}")
                return 0
            if status is None and follow.due(running):
                reply = follow.ask(args.context)
                if reply is None:
                    if follow.down_too_long():
                        say(down_message(args.context, rid[0]))
                        return 1
                elif reply.status is None:
                    say(lost_message(args.context, rid[0]))
                    return 1
                elif reply.status.status != "queued":  # how it ended, or the start we missed
                    status, since = reply.status, reply.at
            if status is not None and status.status in FINAL:
                final = status
                break
            if status is not None and not running:
                running = True
                follow.slot_end = status.end
                begun = since if since is not None else status.start
                left = (status.end or 0) - begun if begun else 0
                say(f"running on {args.agent} for {left:.0f} s; output follows")
                continue
            where = agents.position(rid[0])
            if not running and where is not None and where != shown and where[0] > 0:
                shown = where
                show_wait(*where)
        say(f"{final.status}: {final.reason}")
        return 0 if final.status == "finished" else 1

    return session_for(args, options, body)


if __name__ == "__main__":
    sys.exit(main())
