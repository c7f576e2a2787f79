"""``wart users import`` / ``courses`` / ``course``: a class from a roster file.

  wart users --db DB import class.csv --course robotics-26 [--title "Robotics 2026"]
        [--sheet FILE] [--remove-missing] [--dry-run]
  wart users --db DB courses
  wart users --db DB course robotics-26

The roster is a CSV file (services/registry/roster.py: ``user`` required;
``name``, ``email``, ``role`` student|teacher, ``team``). New accounts get a
first password each, written only to a sheet file readable by its owner alone
(never printed, never logged): hand the slips out, then delete the file.
"""

from __future__ import annotations

import argparse
import html
import os
import time
from pathlib import Path

from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore, ImportReport
from services.registry.roster import RosterError, RosterRow, parse_roster

COMMANDS = ("import", "courses", "course")


def add_parsers(sub: argparse._SubParsersAction) -> None:
    imp = sub.add_parser(
        "import",
        help="make or match the accounts of a class roster (CSV) and put them in a course",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    imp.add_argument("roster", type=Path, help="CSV: user[,name,email,role,team]")
    imp.add_argument("--course", required=True, help="the course's name (a lab identifier)")
    imp.add_argument("--title", default="", help="the course's title (default: its name)")
    imp.add_argument(
        "--sheet",
        type=Path,
        help="where the new accounts' first passwords go (default: beside the database, "
        "first-passwords-COURSE-TIME.html); created readable by you only",
    )
    imp.add_argument(
        "--remove-missing",
        action="store_true",
        help="take members the file does not name out of the course (their accounts stay)",
    )
    imp.add_argument(
        "--dry-run", action="store_true", help="check the file and say what it would do"
    )
    sub.add_parser("courses", help="list the courses and how many members each has")
    show = sub.add_parser("course", help="list a course's teachers and students")
    show.add_argument("course")


def run(args: argparse.Namespace, db: RegistryDB) -> int:
    store = CourseStore(db)
    if args.command == "courses":
        for name, title, members in store.courses():
            print(f"{name:<24} {members:>4} members  {title}")
        return 0
    if args.command == "course":
        for m in store.members(args.course):
            team = f" team {m.team}" if m.team else ""
            print(f"{m.role:<8} {m.user:<20}{team}  {m.name}")
        return 0
    rows = _read(args.roster)
    if args.dry_run:
        print(f"{args.roster}: {len(rows)} people, the file is fine; nothing written (--dry-run)")
        return 0
    sheet = args.sheet or db.path.parent / (
        f"first-passwords-{args.course}-{time.strftime('%Y%m%d-%H%M%S')}.html"
    )
    # The sheet is opened before anything is written: new accounts whose first passwords
    # could not be kept anywhere would be locked out.
    handle = None
    if any(not db.user_exists(r.user) for r in rows):
        try:
            handle = os.open(sheet, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            raise ValueError(f"{sheet} exists: not overwriting a sheet of passwords") from None
    try:
        report = store.import_roster(
            args.course, rows, title=args.title, remove_missing=args.remove_missing
        )
    except BaseException:
        if handle is not None:
            os.close(handle)
            sheet.unlink(missing_ok=True)
        raise
    for line in report.lines():
        print(line)
    if handle is not None:
        with os.fdopen(handle, "w", encoding="utf-8") as f:
            f.write(sheet_html(report, rows, args.title or args.course))
        if not report.passwords:
            sheet.unlink()  # their accounts were made meanwhile, by someone else
        else:
            n = len(report.passwords)
            print(
                f"  first passwords of the {n} new account{'s' * (n != 1)}: {sheet} "
                "(readable by you only; print it, hand out the slips, delete it)"
            )
    return 0


def _read(path: Path) -> list[RosterRow]:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read the roster {path}: {exc.strerror or exc}") from None
    try:
        return parse_roster(raw)
    except RosterError as exc:
        raise ValueError(
            f"{path} was not imported (nothing written):\n  " + "\n  ".join(exc.problems)
        ) from None


def sheet_html(report: ImportReport, rows: list[RosterRow], title: str) -> str:
    """A printable page of slips, one per new account."""
    names = {r.user: r.name for r in rows}
    slips = "\n".join(
        "<div class=slip><b>{}</b> {}<br>user: <code>{}</code><br>first password: "
        "<code>{}</code><br><small>Keep this slip to yourself.</small></div>".format(
            html.escape(title),
            html.escape(names.get(user, "")),
            html.escape(user),
            html.escape(password),
        )
        for user, password in sorted(report.passwords.items())
    )
    return (
        "<!doctype html><meta charset=utf-8><title>First passwords</title><style>"
        ".slip{border:1px dashed #888;padding:8px;margin:6px;display:inline-block;width:300px;"
        "font-family:sans-serif}code{font-size:1.2em}</style>\n" + slips + "\n"
    )
