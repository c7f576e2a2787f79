"""Courses and their members in the registry's database: a class imported from a roster.

A course has teachers and students, each maybe in a team. Importing a roster
makes the accounts it names that do not exist yet (role ``student``, or
``instructor`` for a teacher) with a first password each, and matches the
ones that do; it puts everyone in the course with their role and team. All of
it happens in one transaction: a roster that fails halfway writes nothing.
Importing the same roster again changes nothing and says so; members the
file no longer names stay unless ``remove_missing``.

First passwords are returned to the caller (to print on a sheet for the
teacher), never logged and never stored in clear: the database keeps only
their argon2id hash, like any password.
"""

from __future__ import annotations

import secrets
import sqlite3
import time
from dataclasses import dataclass, field

from common import acl
from common.keys import check_ident
from services.lab.database import ROSTER_SCHEMA
from services.registry.accounts_db import DbError, RegistryDB, hash_password
from services.registry.roster import RosterRow

# Unambiguous when read off paper: no 0/O, 1/l/I.
_ALPHABET = "abcdefghijkmnpqrstuvwxyzABCDEFGHJKLMNPQRSTUVWXYZ23456789"
FIRST_PASSWORD_LENGTH = 12
ACCOUNT_ROLE = {"student": "student", "teacher": "instructor"}


def first_password() -> str:
    return "".join(secrets.choice(_ALPHABET) for _ in range(FIRST_PASSWORD_LENGTH))


@dataclass(frozen=True)
class Member:
    user: str
    role: str
    team: str
    name: str
    email: str


@dataclass
class ImportReport:
    """What an import did, name by name (passwords: the new accounts' first passwords)."""

    course: str
    created_course: bool = False
    new_accounts: list[str] = field(default_factory=list)
    joined: list[str] = field(default_factory=list)  # accounts that existed, now in the course
    changed: list[str] = field(default_factory=list)  # role, team, name or email changed
    unchanged: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)  # members the file does not name
    removed: list[str] = field(default_factory=list)  # ... taken out (remove_missing)
    passwords: dict[str, str] = field(default_factory=dict, repr=False)

    def lines(self) -> list[str]:
        """What the teacher is told, in words (no password)."""
        out = [f"course {self.course}" + (" (new)" if self.created_course else "") + ":"]
        for what, names in (
            ("new accounts", self.new_accounts),
            ("existing accounts joined", self.joined),
            ("changed", self.changed),
            ("removed from the course", self.removed),
        ):
            if names:
                out.append(f"  {what} ({len(names)}): {', '.join(names)}")
        out.append(f"  unchanged: {len(self.unchanged)}")
        if self.missing:
            out.append(
                f"  not in this file, kept ({len(self.missing)}): {', '.join(self.missing)} "
                "(--remove-missing takes them out of the course)"
            )
        return out


class CourseStore:
    """Courses and members, beside the accounts in the registry's database."""

    def __init__(self, db: RegistryDB) -> None:
        self.db = db
        db.database.create(ROSTER_SCHEMA, "course tables")

    def courses(self) -> list[tuple[str, str, int]]:
        """(name, title, members) of every course."""
        rows = self.db._rows(
            "SELECT c.name, c.title, COUNT(m.user) FROM courses c "
            "LEFT JOIN course_members m ON m.course = c.name GROUP BY c.name ORDER BY c.name"
        )
        return [(str(n), str(t), int(k)) for n, t, k in rows]

    def members(self, course: str) -> list[Member]:
        if not self.db._rows("SELECT 1 FROM courses WHERE name=?", course):
            raise DbError("not_found", f"no course named {course}")
        rows = self.db._rows(
            "SELECT user, role, team, display_name, email FROM course_members "
            "WHERE course=? ORDER BY role DESC, team, user",
            course,
        )
        return [Member(*map(str, r)) for r in rows]

    def import_roster(
        self,
        course: str,
        rows: list[RosterRow],
        *,
        title: str = "",
        remove_missing: bool = False,
    ) -> ImportReport:
        """Put ``rows`` in ``course`` (made if new), making the accounts that do not exist."""
        try:
            check_ident("course", course)
        except ValueError as exc:
            raise DbError("bad_request", str(exc)) from None
        report = ImportReport(course=course)
        # Hashing is the slow part (argon2id, ~50 ms each): done before the transaction,
        # for the names that have no account now; a name made meanwhile is matched instead.
        existing = {str(r[0]) for r in self.db._rows("SELECT name FROM users")}
        hashes: dict[str, bytes] = {}
        for row in rows:
            if row.user not in existing:
                report.passwords[row.user] = first_password()
                hashes[row.user] = hash_password(report.passwords[row.user])
        now = time.time()
        with self.db._tx() as con:
            if not con.execute("SELECT 1 FROM courses WHERE name=?", (course,)).fetchone():
                con.execute(
                    "INSERT INTO courses(name, title, created_at) VALUES (?, ?, ?)",
                    (course, title or course, now),
                )
                report.created_course = True
            elif title:
                con.execute("UPDATE courses SET title=? WHERE name=?", (title, course))
            before = {
                str(r[0]): tuple(map(str, r[1:]))
                for r in con.execute(
                    "SELECT user, role, team, display_name, email FROM course_members "
                    "WHERE course=?",
                    (course,),
                )
            }
            for row in rows:
                self._account(con, row, hashes, report, now)
                values = (row.role, row.team, row.name, row.email)
                old = before.pop(row.user, None)
                if old == values:
                    report.unchanged.append(row.user)
                    continue
                con.execute(
                    "INSERT OR REPLACE INTO course_members"
                    "(course, user, role, team, display_name, email) VALUES (?, ?, ?, ?, ?, ?)",
                    (course, row.user, *values),
                )
                if old is not None:
                    report.changed.append(row.user)
                elif row.user not in report.new_accounts:
                    report.joined.append(row.user)
            report.missing = sorted(before)
            if remove_missing:
                for user in report.missing:
                    con.execute(
                        "DELETE FROM course_members WHERE course=? AND user=?", (course, user)
                    )
                report.removed, report.missing = report.missing, []
        report.passwords = {u: p for u, p in report.passwords.items() if u in report.new_accounts}
        return report

    @staticmethod
    def _account(
        con: sqlite3.Connection,
        row: RosterRow,
        hashes: dict[str, bytes],
        report: ImportReport,
        now: float,
    ) -> None:
        """Make ``row``'s account if there is none (with its first password and role)."""
        if con.execute("SELECT 1 FROM users WHERE name=?", (row.user,)).fetchone():
            return
        hashed = hashes.get(row.user)
        if hashed is None:  # no hash made: the account existed a moment ago and was removed
            raise DbError(
                "conflict", f"user {row.user} was removed during the import: run it again"
            )
        con.execute("INSERT INTO users(name, created_at) VALUES (?, ?)", (row.user, now))
        con.execute(
            "INSERT INTO grants(user, scope, grant_name) VALUES (?, '', ?)",
            (row.user, acl.ROLE_PREFIX + ACCOUNT_ROLE[row.role]),
        )
        con.execute(
            "INSERT INTO credentials(user, kind, data) VALUES (?, 'password', ?)",
            (row.user, hashed),
        )
        report.new_accounts.append(row.user)
