"""``wart leaderboard ASSIGNMENT``: the best score of each student, best first.

    wart leaderboard reach-goal --user alice

    wart leaderboard reach-goal --user alice --pseudonym "Speedy"   # show as Speedy

Names are the course roster's display names (or the account), or the
pseudonym a student chose (unique in the course; teachers see both). Where the
assignment hides scores until its deadline, students see that it is hidden;
the course's teachers see it all along.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

from common import cli
from common.client.grader_client import GraderClient
from services.commands.submit import grader_session
from services.commands.terminal import say


def main(argv: Sequence[str] | None = None, prog: str = "wart leaderboard") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("assignment")
    p.add_argument("--user", required=True)
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("--grader", default="grader", help="the grader's name (default grader)")
    p.add_argument(
        "--pseudonym",
        metavar="NAME",
        help="first show under NAME on the course's leaderboards ('' for your roster name)",
    )
    args, options = cli.parse_networked(p, argv)

    def body(grader: GraderClient) -> int:
        if args.pseudonym is not None:
            say(grader.set_pseudonym(args.assignment, args.pseudonym))
        board = grader.leaderboard(args.assignment)
        better = "higher" if board.order == "higher" else "lower"
        unit = f" ({board.unit})" if board.unit else ""
        say(f"{board.assignment}: {board.score_name}{unit}, {better} is better")
        when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(board.deadline))
        until = board.hidden_until or f"until the deadline, {when}"
        if board.hidden and not board.entries:
            say(f"  hidden: {until}")
            return 0
        if board.hidden:
            say(f"  (hidden from students: {until}; you see it as a teacher)")
        for e in board.entries:
            real = f"  real {e.real:g}" if e.real is not None else ""
            say(f"  {e.rank:>3}. {e.name:<24} {e.score:>10g}  {e.submission}{real}")
        if not board.entries:
            say("  no graded submission yet")
        return 0

    return grader_session(args, options, body)


if __name__ == "__main__":
    sys.exit(main())
