"""``wart course competition``: every team's entry on one arena, in heats, ranked live.

    wart course competition run reach-goal --user ida [--name final] [--pick best] [--wait]
    wart course competition show final --user ida

``run`` (the course's teachers) takes each team's latest (or best) graded
submission as its entry (a student with no team is a team of one) and runs
them in heats, one entry a heat, on the assignment's map with its first start
pose and seed; with ``--wait`` it prints the standings as each heat ends until
the last. ``show`` prints a competition's standings (anyone in the course) and
where each heat's recording (MCAP) is. docs/COURSES.md.
"""

from __future__ import annotations

import argparse
import queue
import sys
import time
from collections.abc import Sequence

from common import cli, keys
from common.client.grader_client import GraderClient
from common.messages import Standings
from services.commands.submit import grader_session
from services.commands.terminal import say


def print_standings(st: Standings) -> None:
    better = "higher" if st.order == "higher" else "lower"
    unit = f" ({st.unit})" if st.unit else ""
    where = f"heat {st.heat} of {st.heats} running" if st.status == "running" and st.heat else ""
    say(
        f"competition {st.competition} on {st.assignment} ({st.course}): {st.status}"
        + (f", {where}" if where else f", {st.heats} heat(s)")
        + f"; {st.score_name}{unit}, {better} is better"
    )
    for e in st.entries:
        rank = f"{e.rank:>3}." if e.rank else "  -."
        score = "-" if e.score is None else f"{e.score:g}"
        say(f"  {rank} {e.team:<20} {score:>10}  heat {e.heat}  {e.user} {e.submission}")
        if e.cause != "waiting":
            say(f"       {e.cause}: {e.detail}")
        if e.recording:
            say(f"       recording: {e.recording}")


def main(argv: Sequence[str] | None = None, prog: str = "wart course competition") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("action", choices=("run", "show"))
    p.add_argument("target", help="run: the assignment; show: the competition's name")
    p.add_argument("--user", required=True)
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("--grader", default="grader", help="the grader's name (default grader)")
    p.add_argument("--name", help="run: the competition's name (default: assignment and time)")
    p.add_argument("--pick", choices=("latest", "best"), default="latest")
    p.add_argument(
        "--per-heat",
        type=int,
        default=1,
        help="entries in one world at once, each on its own robot (default 1)",
    )
    p.add_argument("--wait", type=float, metavar="S", help="run: print standings until done")
    args, options = cli.parse_networked(p, argv)
    try:
        keys.check_ident("competition", args.target)
        if args.name is not None:
            keys.check_ident("competition name", args.name)
    except ValueError as exc:
        return cli.fail(str(exc))
    # grader_session checks an assignment's name; a competition's is the same kind of ident.
    session_args = argparse.Namespace(**{**vars(args), "assignment": args.target})

    def body(grader: GraderClient) -> int:
        if args.action == "show":
            print_standings(grader.standings(args.target))
            return 0
        seen: queue.Queue[Standings] = queue.Queue()
        stop = None
        if args.wait is not None and args.name:
            stop = grader.watch_standings(args.name, seen.put)
        first = grader.run_competition(args.target, args.name, args.pick, args.per_heat)
        print_standings(first)
        if args.wait is None:
            return 0
        if stop is None:  # the name was the grader's choice: watch it now
            stop = grader.watch_standings(first.competition, seen.put)
        deadline = time.monotonic() + args.wait
        try:
            while time.monotonic() < deadline:
                try:
                    st = seen.get(timeout=1.0)
                except queue.Empty:
                    continue
                if st.status != "running" or any(e.cause != "waiting" for e in st.entries):
                    print_standings(st)
                if st.status == "finished":
                    return 0
                if st.status == "stopped":
                    return cli.fail("the grader stopped during the competition", 1)
            # Published ones may be missed (joined late): the grader still has the last.
            st = grader.standings(first.competition)
            print_standings(st)
            return 0 if st.status == "finished" else cli.fail("not finished in time", 1)
        finally:
            stop()

    return grader_session(session_args, options, body)


if __name__ == "__main__":
    sys.exit(main())
