"""``wart course``: a course's assignments, written by its teacher (the registry's database).

  wart course --db DB assignment add reach-goal.toml [--maps DIR]
  wart course --db DB assignment check reach-goal.toml [--maps DIR]
  wart course --db DB assignments [COURSE]
  wart course --db DB release ASSIGNMENT      (its "after_release" results shown to students)
  wart course competition run ASSIGNMENT --user TEACHER [--wait S]   (over the lab)
  wart course competition show NAME --user USER

The file's format is docs/COURSES.md. A file with problems is refused whole,
each problem with its field; adding it again replaces it (same name).
Works on the SQLite file while the registry and the grader run (WAL).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from common.acl import agent_scope
from services.grader.assignment import AssignmentError, parse_assignment
from services.grader.grading_db import GradingStore
from services.lab.database import DbError
from services.lab.lab_maps import SHIPPED_MAPS
from services.lab.wiring import service_account
from services.registry.accounts_db import RegistryDB


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(t))


def main(argv: Sequence[str] | None = None, prog: str = "wart course") -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    p = argparse.ArgumentParser(
        prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--db", type=Path, required=True, help="the registry's SQLite database")
    sub = p.add_subparsers(dest="command", required=True)
    a = sub.add_parser("assignment", help="add (or replace) or check an assignment file")
    a.add_argument("action", choices=("add", "check"))
    a.add_argument("file", type=Path, help="the assignment (TOML)")
    a.add_argument("--maps", type=Path, default=SHIPPED_MAPS, help="the maps directory")
    a.add_argument(
        "--grader-account",
        default=service_account("grader", "grader"),
        help="the grader's service account, granted deploy on a [real] arena's robot",
    )
    ls = sub.add_parser("assignments", help="list the assignments (of a course)")
    ls.add_argument("course", nargs="?")
    rel = sub.add_parser(
        "release",
        help='show an assignment\'s "after_release" results (and its leaderboard) to students',
    )
    rel.add_argument("assignment")
    args = p.parse_args(argv)
    if not args.db.exists():
        print(f"{prog}: {args.db}: no registry database there", file=sys.stderr)
        return 2
    db = RegistryDB(args.db)
    try:
        store = GradingStore(db.database)
        if args.command == "release":
            try:
                at = store.release(args.assignment)
            except DbError as exc:
                print(f"{prog}: {exc}", file=sys.stderr)
                return 1
            print(f"{args.assignment}: results released to its students ({_when(at)})")
            return 0
        if args.command == "assignments":
            for x in store.assignments(args.course):
                print(
                    f"{x.name:<20} {x.course:<16} map {x.map_name}, {x.episodes} episodes of "
                    f"{x.time_limit:g} s, due {_when(x.deadline)}, quota {x.quota}/24 h"
                )
                if x.grader_file:
                    failed, latest = store.grader_failures(x.name)
                    print(f"  grader {x.grader_file}: {failed} submission(s) it failed")
                    if failed:
                        print(f"  latest: {latest}")
            return 0
        try:
            raw = args.file.read_bytes()
        except OSError as exc:
            print(f"{prog}: cannot read {args.file}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        try:
            assignment, map_text = parse_assignment(
                raw, str(args.file), args.maps, base=args.file.parent
            )
        except AssignmentError as exc:
            print(f"{args.file} was refused (nothing written):", file=sys.stderr)
            for problem in exc.problems:
                print(f"  {problem}", file=sys.stderr)
            return 1
        if args.action == "check":
            print(f"{args.file}: assignment {assignment.name} is fine; nothing written")
            return 0
        if assignment.real_arena:
            # The grader queues the real attempt as itself: it may deploy on that robot.
            scope = agent_scope(assignment.real_arena, assignment.real_robot)
            try:
                db.grant(args.grader_account, "deploy", scope)
            except DbError as exc:
                print(f"{args.file} was refused (nothing written):", file=sys.stderr)
                print(f"  real: the grader's account {args.grader_account}: {exc}",
                      file=sys.stderr)  # fmt: skip
                return 1
        new = store.put_assignment(assignment, map_text)
        print(
            f"assignment {assignment.name} {'added' if new else 'replaced'} in course "
            f"{assignment.course}: {assignment.episodes} episodes of {assignment.time_limit:g} "
            f"simulated s on {assignment.map_name}, opens {_when(assignment.opens)}, "
            f"due {_when(assignment.deadline)}"
            + (f"; grader {assignment.grader_file} stored with it" * bool(assignment.grader_file))
        )
        if assignment.real_arena:
            print(
                f"real-robot attempt on {assignment.real_arena}/{assignment.real_robot} "
                f"({assignment.real_after}); {args.grader_account} may deploy there"
            )
        return 0
    except DbError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 1
    finally:
        db.close()


if __name__ == "__main__":
    sys.exit(main())
