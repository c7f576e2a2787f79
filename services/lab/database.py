"""The lab's database: one SQLite file (WAL) that the registry and the grader share.

Each process opens the file through :class:`LabDatabase` and keeps to its own
tables: the registry its accounts, sessions, courses, bans and audit; the grader
its assignments, submissions and episodes. The course roster (``courses``,
``course_members``) is the one thing they share: the registry writes it
(``wart users import``, LTI launches), the grader reads it, and its schema is
here, the contract between the two. WAL lets the registry, the grader and the
offline tools (``wart users``, ``wart course``) read and write at once.
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from common.messages import ErrorCode

ROSTER_SCHEMA = """
CREATE TABLE IF NOT EXISTS courses (
    name TEXT PRIMARY KEY,
    title TEXT NOT NULL,
    created_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS course_members (
    course TEXT NOT NULL REFERENCES courses(name) ON DELETE CASCADE,
    user TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    role TEXT NOT NULL,
    team TEXT NOT NULL DEFAULT '',
    display_name TEXT NOT NULL DEFAULT '',
    email TEXT NOT NULL DEFAULT '',
    PRIMARY KEY (course, user)
);
"""


class DbError(ValueError):
    """A request to the database is wrong (unknown user, name taken, bad grant)."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


class LabDatabase:
    """One connection to the lab's database, shared by a process's threads (one lock)."""

    def __init__(self, path: Path, what: str = "registry") -> None:
        self.path = path
        path.parent.mkdir(parents=True, exist_ok=True)
        self.created = not path.exists()
        try:
            self._connection = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self._connection.execute("PRAGMA journal_mode=WAL")
            self._connection.execute("PRAGMA foreign_keys=ON")
            self._connection.execute("PRAGMA busy_timeout=5000")
        except sqlite3.DatabaseError as exc:
            raise DbError("internal", f"cannot open the {what} database {path}: {exc}") from None
        self._lock = threading.RLock()

    def close(self) -> None:
        with self._lock:
            self._connection.close()

    def create(self, schema: str, what: str) -> None:
        """Create the tables of ``schema`` that are not there yet (``what`` names them)."""
        try:
            with self._lock:
                self._connection.executescript(schema)
        except sqlite3.DatabaseError as exc:
            raise DbError("internal", f"cannot create the {what}: {exc}") from None

    def columns(self, table: str) -> set[str]:
        with self._lock:
            return {row[1] for row in self._connection.execute(f"PRAGMA table_info({table})")}

    @contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """One write transaction (BEGIN IMMEDIATE): committed, or rolled back on any error."""
        with self._lock:
            self._connection.execute("BEGIN IMMEDIATE")
            try:
                yield self._connection
            except BaseException:
                self._connection.execute("ROLLBACK")
                raise
            self._connection.execute("COMMIT")

    def rows(self, sql: str, *args: object) -> list[tuple]:
        with self._lock:
            return list(self._connection.execute(sql, args))
