"""The lti service's own small database (in the lab's state directory).

``launches``: which platform user (issuer, sub) a lab account is, and the line
item of each assignment they launched, so a graded submission finds where its
score goes. ``scores``: the outbox of grade passback, one row per submission
(its primary key: a score is posted once, however often the grader says so),
with its attempts, the next try and the last error in words. A score waits here
across a platform's outage and the service's restarts: nothing is lost.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path

SCHEMA = """
CREATE TABLE IF NOT EXISTS launches (
    user TEXT NOT NULL,
    assignment TEXT NOT NULL,
    issuer TEXT NOT NULL,
    client_id TEXT NOT NULL,
    subject TEXT NOT NULL,
    lineitem TEXT NOT NULL,
    at REAL NOT NULL,
    PRIMARY KEY (user, assignment)
);
CREATE TABLE IF NOT EXISTS scores (
    submission TEXT PRIMARY KEY,
    user TEXT NOT NULL,
    assignment TEXT NOT NULL,
    issuer TEXT NOT NULL,
    client_id TEXT NOT NULL,
    subject TEXT NOT NULL,
    lineitem TEXT NOT NULL,
    score REAL NOT NULL,
    maximum REAL NOT NULL,
    graded_at REAL NOT NULL,
    status TEXT NOT NULL DEFAULT 'waiting',
    attempts INTEGER NOT NULL DEFAULT 0,
    next_at REAL NOT NULL,
    error TEXT NOT NULL DEFAULT ''
);
"""


@dataclass(frozen=True)
class LaunchLink:
    issuer: str
    client_id: str
    subject: str
    lineitem: str


@dataclass(frozen=True)
class Outgoing:
    submission: str
    user: str
    assignment: str
    issuer: str
    client_id: str
    subject: str
    lineitem: str
    score: float
    maximum: float
    graded_at: float
    attempts: int


class LtiStore:
    def __init__(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Platform user ids and scores: the tool's alone (SQLite gives its -wal and -shm
        # files the database file's mode).
        os.close(os.open(path, os.O_CREAT | os.O_RDWR, 0o600))
        path.chmod(0o600)
        self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.executescript(SCHEMA)
        self._lock = threading.Lock()

    def close(self) -> None:
        with self._lock:
            self._db.close()

    def record_launch(self, user: str, assignment: str, link: LaunchLink) -> None:
        with self._lock:
            # ``at`` stays the first launch's: scores graded since then are passed back.
            self._db.execute(
                "INSERT INTO launches VALUES (?, ?, ?, ?, ?, ?, ?) ON CONFLICT(user, assignment) "
                "DO UPDATE SET issuer=excluded.issuer, client_id=excluded.client_id, "
                "subject=excluded.subject, lineitem=excluded.lineitem",
                (user, assignment, link.issuer, link.client_id, link.subject, link.lineitem,
                 time.time()),
            )  # fmt: skip

    def launch_of(self, user: str, assignment: str) -> LaunchLink | None:
        with self._lock:
            row = self._db.execute(
                "SELECT issuer, client_id, subject, lineitem FROM launches "
                "WHERE user=? AND assignment=?",
                (user, assignment),
            ).fetchone()
        return None if row is None else LaunchLink(*map(str, row))

    def launches(self) -> list[tuple[str, str, float]]:
        """(user, assignment, first launch) of every launch with grade passback."""
        with self._lock:
            rows = self._db.execute("SELECT user, assignment, at FROM launches").fetchall()
        return [(str(u), str(a), float(t)) for u, a, t in rows]

    def known(self, submission: str) -> bool:
        with self._lock:
            row = self._db.execute(
                "SELECT 1 FROM scores WHERE submission=?", (submission,)
            ).fetchone()
        return row is not None

    def enqueue(self, out: Outgoing) -> bool:
        """Keep a score to post; False if this submission's score is already kept."""
        with self._lock:
            cur = self._db.execute(
                "INSERT OR IGNORE INTO scores(submission, user, assignment, issuer, client_id, "
                "subject, lineitem, score, maximum, graded_at, next_at) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (out.submission, out.user, out.assignment, out.issuer, out.client_id,
                 out.subject, out.lineitem, out.score, out.maximum, out.graded_at, time.time()),
            )  # fmt: skip
            return cur.rowcount == 1

    def due(self, now: float, limit: int = 20) -> list[Outgoing]:
        with self._lock:
            rows = self._db.execute(
                "SELECT submission, user, assignment, issuer, client_id, subject, lineitem, "
                "score, maximum, graded_at, attempts FROM scores "
                "WHERE status='waiting' AND next_at<=? ORDER BY next_at LIMIT ?",
                (now, limit),
            ).fetchall()
        return [Outgoing(*r) for r in rows]

    def next_due(self) -> float | None:
        with self._lock:
            row = self._db.execute(
                "SELECT MIN(next_at) FROM scores WHERE status='waiting'"
            ).fetchone()
        return None if row is None or row[0] is None else float(row[0])

    def sent(self, submission: str) -> None:
        self._set(submission, "sent", "", None)

    def failed(self, submission: str, error: str) -> None:
        """Given up: the platform refused it for good (a 4xx); the reason is kept."""
        self._set(submission, "refused", error, None)

    def retry(self, submission: str, error: str, at: float) -> None:
        self._set(submission, "waiting", error, at)

    def _set(self, submission: str, status: str, error: str, at: float | None) -> None:
        with self._lock:
            self._db.execute(
                "UPDATE scores SET status=?, error=?, attempts=attempts+1, "
                "next_at=COALESCE(?, next_at) WHERE submission=?",
                (status, error[:500], at, submission),
            )

    def status(self, submission: str) -> tuple[str, int, str] | None:
        """(status, attempts, last error) of a submission's score: waiting, sent or refused."""
        with self._lock:
            row = self._db.execute(
                "SELECT status, attempts, error FROM scores WHERE submission=?", (submission,)
            ).fetchone()
        return None if row is None else (str(row[0]), int(row[1]), str(row[2]))
