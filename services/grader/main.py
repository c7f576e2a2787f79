"""``wart grader``: the command line; what the service does is service.py's docstring."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli
from common.client.service_login import ServiceCredentials
from common.service import run_service
from services.grader import service
from services.grader.episodes import RUNNER_WAIT_S
from services.grader.grading_db import GradingStore
from services.grader.service import WORKERS, GraderService
from services.lab.database import DbError, LabDatabase


def main(argv: Sequence[str] | None = None, prog: str = "wart grader") -> int:
    p = cli.parser(prog, service.__doc__ or "")
    cli.add_account_arguments(
        p,
        "grader",
        "the grader's id (default grader)",
        "the grader's service account (with 'lease')",
    )
    p.add_argument(
        "--db",
        type=Path,
        required=True,
        help="the registry's database (assignments, courses; submissions are written there)",
    )
    p.add_argument(
        "--workers", type=int, default=WORKERS, help=f"submissions graded at once ({WORKERS})"
    )
    p.add_argument(
        "--runner-wait",
        type=float,
        default=RUNNER_WAIT_S,
        metavar="S",
        help=f"how long an episode waits for a live runner before the lab is at fault "
        f"(default {RUNNER_WAIT_S:g})",
    )
    p.add_argument(
        "--competitions",
        type=Path,
        metavar="DIR",
        help="competitions' standings and heat recordings (default: competitions/ beside --db)",
    )
    p.add_argument(
        "--episode-recordings",
        type=Path,
        metavar="DIR",
        help="each graded episode's recording, which its student replays "
        "(default: graded/ beside --db)",
    )
    args, options = cli.parse_networked(p, argv)
    try:
        credentials = ServiceCredentials.of_service("grader", args, options)
    except ValueError as exc:
        return cli.fail(str(exc))
    if not 1 <= args.workers <= 64:
        return cli.fail("--workers must be 1..64")
    if not 0.5 <= args.runner_wait <= 3600:
        return cli.fail("--runner-wait must be 0.5..3600 s")
    if not args.db.exists():
        return cli.fail(f"{args.db}: no registry database there (start the registry first)")
    try:
        db = LabDatabase(args.db)
        store = GradingStore(db)
    except DbError as exc:
        return cli.fail(str(exc))

    def build(session: zenoh.Session) -> GraderService:
        login = credentials.login(session, options.realm, f"grader {args.name}")
        return GraderService(
            session,
            options.realm,
            args.name,
            registry_key=credentials.registry_key,
            login=login,
            store=store,
            workers=args.workers,
            runner_wait=args.runner_wait,
            competitions=args.competitions or args.db.parent / "competitions",
            graded=args.episode_recordings or args.db.parent / "graded",
        )

    try:
        return run_service(f"grader {args.name}", options, build)
    finally:
        db.close()


if __name__ == "__main__":
    sys.exit(main())
