"""``wart submit``: hand a controller in to an assignment; it is graded automatically.

    wart submit --assignment reach-goal --user alice my_controller.py [--wait]
    wart submit --assignment reach-goal --user alice --list
    wart submit --assignment reach-goal --user alice --episode SUBMISSION N [-o FILE]

The grader runs the assignment's seeded episodes in simulation and scores
them; ``--wait`` waits for the score and prints the per-episode table (how
each episode ended: your code's fault, with the line, or the lab's, re-run
free). ``--list`` shows your submissions and their scores. ``--episode``
downloads one graded episode's recording (an MCAP file: ``wart report`` reads
it, the page replays it). docs/COURSES.md.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from common import cli, keys
from common.client.grader_client import GraderClient, submitted_words
from common.messages import SubmissionInfo
from common.zconfig import NetworkOptions
from services.commands.terminal import run_logged_in, say


def grader_session(
    args: argparse.Namespace, options: NetworkOptions, body: Callable[[GraderClient], int]
) -> int:
    """Connect, log in and run ``body`` with the grader; errors become clear messages."""
    try:
        keys.check_ident("user", args.user)
        keys.check_ident("assignment", args.assignment)
    except ValueError as exc:
        return cli.fail(str(exc))
    return run_logged_in(args, options, lambda client: body(GraderClient(client, args.grader)))


def show(sub: SubmissionInfo) -> None:
    score = "" if sub.mean is None else f"  mean {sub.mean:g}, min {sub.min:g}"
    if sub.penalty:
        score += f" (late {sub.late_days} day(s): {abs(sub.penalty):g} off)"
    say(f"{sub.submission}  {sub.status}{score}  {sub.message}")
    for e in sub.episodes:
        value = "-" if e.score is None else f"{e.score:g}"
        which = "real robot" if e.real else f"episode {e.episode} (seed {e.seed})"
        replay = "  (replay kept)" if e.replay else ""
        say(f"  {which}: {value:>8}  {e.cause}: {e.detail}{replay}")


def main(argv: Sequence[str] | None = None, prog: str = "wart submit") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("file", nargs="?", type=Path, help="the controller (.py)")
    p.add_argument("--assignment", required=True)
    p.add_argument("--user", required=True)
    p.add_argument("--password-file", help="read the password from this file")
    p.add_argument("--grader", default="grader", help="the grader's name (default grader)")
    p.add_argument("--wait", type=float, nargs="?", const=600.0, metavar="S",
                   help="wait for the score (at most S s, default 600)")  # fmt: skip
    p.add_argument("--list", action="store_true", help="your submissions and their scores")
    p.add_argument("--episode", nargs=2, metavar=("SUBMISSION", "N"),
                   help="download graded episode N of SUBMISSION's recording")  # fmt: skip
    p.add_argument("-o", "--out", type=Path, metavar="FILE",
                   help="where --episode writes (default SUBMISSION-episode-N.mcap)")  # fmt: skip
    args, options = cli.parse_networked(p, argv)
    episode: tuple[str, int] | None = None
    if args.episode is not None:
        sub_id, n = args.episode
        try:
            keys.check_ident("submission", sub_id)
        except ValueError as exc:
            return cli.fail(f"--episode SUBMISSION N: {exc}")
        if not n.isdigit():
            return cli.fail(
                f"--episode SUBMISSION N: N is an episode's number (0, 1, ...), not {n!r}"
            )
        episode = (sub_id, int(n))
    elif not args.list and args.file is None:
        return cli.fail("name the controller file to submit (or --list, or --episode)")
    source = b""
    if args.file is not None:
        try:
            source = args.file.read_bytes()
        except OSError as exc:
            return cli.fail(f"cannot read {args.file}: {exc.strerror or exc}")

    def body(grader: GraderClient) -> int:
        if episode is not None:
            out = args.out or Path(f"{episode[0]}-episode-{episode[1]}.mcap")
            grader.fetch_episode(args.assignment, episode[0], episode[1], out)
            say(f"episode {episode[1]} of {episode[0]} written to {out} (wart report {out})")
            return 0
        if args.list:
            for sub in grader.submissions(args.assignment):
                show(sub)
            return 0
        accepted = grader.submit(args.assignment, source, args.file.name)
        say(submitted_words(accepted))
        if args.wait is None:
            return 0
        try:
            show(grader.wait_graded(args.assignment, accepted.submission, args.wait))
        except TimeoutError as exc:
            return cli.fail(f"{exc}: see it later with --list", 1)
        return 0

    return grader_session(args, options, body)


if __name__ == "__main__":
    sys.exit(main())
