"""LTI users in the registry's database: a platform's user linked to a lab account.

A launch from an LMS names its user by the platform (issuer) and an id there
(``sub``). The first launch makes a lab account for them (no password: they come
in through the LMS, or an admin gives them one), later launches find it by the
link. Each launch also puts the account in the launch's course with the role
the LMS gives (a teacher stays a teacher: a launch never lowers a role), and
mints a resume token (services/registry/resume.py) the page logs in with once.
All of it is one transaction: a refused launch writes nothing.

Only a session of an account with the ``lti`` role may ask (docs/SECURITY.md,
"LTI 1.3"); every answer lands in the audit trail.
"""

from __future__ import annotations

import hashlib
import secrets
import time

from common import acl
from common.messages import LtiAccount, LtiAccountRequest
from services.registry.accounts_db import DbError, RegistryDB
from services.registry.courses_db import ACCOUNT_ROLE, CourseStore
from services.registry.resume import ResumeStore

SCHEMA = """
CREATE TABLE IF NOT EXISTS lti_links (
    issuer TEXT NOT NULL,
    subject TEXT NOT NULL,
    user TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    created_at REAL NOT NULL,
    last_launch REAL NOT NULL,
    PRIMARY KEY (issuer, subject)
);
"""

LAUNCH_LOGIN_S = 600.0
"""How long a launch's resume token is good: the browser uses it within seconds."""

RANK = {"student": 0, "teacher": 1}


def account_name(issuer: str, subject: str) -> str:
    """A new account's name: stable per platform user, and no guess from outside the LMS."""
    digest = hashlib.blake2b(f"{issuer}\n{subject}".encode(), digest_size=5).hexdigest()
    return f"lms-{digest}"


class LtiLinks:
    """Platform users -> lab accounts, and what a launch does to them."""

    def __init__(self, db: RegistryDB, resumes: ResumeStore) -> None:
        self.db = db
        self.resumes = resumes
        CourseStore(db)  # the course tables exist before a launch joins one
        db.database.create(SCHEMA, "LTI link table")

    def user_of(self, issuer: str, subject: str) -> str | None:
        rows = self.db._rows(
            "SELECT user FROM lti_links WHERE issuer=? AND subject=?", issuer, subject
        )
        return str(rows[0][0]) if rows else None

    def launch(self, request: LtiAccountRequest, now: float | None = None) -> LtiAccount:
        """The account of the request's user, made and put in its course as needed."""
        now = time.time() if now is None else now
        created = joined = False
        with self.db._tx() as con:
            if not con.execute("SELECT 1 FROM courses WHERE name=?", (request.course,)).fetchone():
                raise DbError(
                    "not_found",
                    f"no course named {request.course} in this lab: import its roster "
                    "(wart users import) or map the LMS's course to one (the lti config)",
                )
            row = con.execute(
                "SELECT user FROM lti_links WHERE issuer=? AND subject=?",
                (request.issuer, request.subject),
            ).fetchone()
            if row is None:
                user = account_name(request.issuer, request.subject)
                if con.execute("SELECT 1 FROM users WHERE name=?", (user,)).fetchone():
                    raise DbError("conflict", f"an account {user} exists and is not this user's")
                con.execute("INSERT INTO users(name, created_at) VALUES (?, ?)", (user, now))
                con.execute(
                    "INSERT INTO grants(user, scope, grant_name) VALUES (?, '', ?)",
                    (user, acl.ROLE_PREFIX + ACCOUNT_ROLE[request.role]),
                )
                con.execute(
                    "INSERT INTO lti_links(issuer, subject, user, created_at, last_launch) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (request.issuer, request.subject, user, now, now),
                )
                created = True
            else:
                user = str(row[0])
                con.execute(
                    "UPDATE lti_links SET last_launch=? WHERE issuer=? AND subject=?",
                    (now, request.issuer, request.subject),
                )
            member = con.execute(
                "SELECT role FROM course_members WHERE course=? AND user=?",
                (request.course, user),
            ).fetchone()
            if member is None:
                con.execute(
                    "INSERT INTO course_members(course, user, role, team, display_name, email) "
                    "VALUES (?, ?, ?, '', ?, ?)",
                    (request.course, user, request.role, request.name, request.email),
                )
                joined = True
            elif RANK.get(request.role, 0) > RANK.get(str(member[0]), 0):
                con.execute(
                    "UPDATE course_members SET role=? WHERE course=? AND user=?",
                    (request.role, request.course, user),
                )
                joined = True
        # A session id of its own: the token belongs to no session yet (the page's
        # resume makes one), and nothing but its use or the account's end revokes it.
        token = self.resumes.issue(user, secrets.token_bytes(16), now + LAUNCH_LOGIN_S, now)
        return LtiAccount(user=user, created=created, joined=joined, resume=token)


__all__ = ["LAUNCH_LOGIN_S", "LtiLinks", "account_name"]
