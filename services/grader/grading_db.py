"""Assignments, submissions and their episodes, in the registry's database (beside courses).

One database for the class: the teacher's CLI writes assignments there
(``wart course assignment add``), the grader (which runs on the registry's
host, `wart up` puts it there) reads them and writes submissions and results;
SQLite's WAL lets both work at once. A submission is written before it is
queued, so a grader that dies finds its queue again at start (``pending``):
those runs re-run, the lab's fault, free.
"""

from __future__ import annotations

import json
import sqlite3
import time
import uuid
from dataclasses import dataclass

from common.messages import EpisodeResult, SubmissionInfo
from services.grader.assignment import Assignment
from services.lab.database import ROSTER_SCHEMA, DbError, LabDatabase

SCHEMA = """
CREATE TABLE IF NOT EXISTS assignments (
    name TEXT PRIMARY KEY,
    course TEXT NOT NULL REFERENCES courses(name),
    spec TEXT NOT NULL,
    map TEXT NOT NULL,
    updated_at REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS submissions (
    id TEXT PRIMARY KEY,
    assignment TEXT NOT NULL REFERENCES assignments(name) ON DELETE CASCADE,
    user TEXT NOT NULL,
    submitted_at REAL NOT NULL,
    filename TEXT NOT NULL,
    source BLOB NOT NULL,
    status TEXT NOT NULL,
    counted INTEGER NOT NULL DEFAULT 1,
    late_days INTEGER NOT NULL DEFAULT 0,
    penalty REAL NOT NULL DEFAULT 0,
    mean REAL,
    min REAL,
    graded_at REAL,
    message TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS submissions_by_user ON submissions(assignment, user, submitted_at);
CREATE TABLE IF NOT EXISTS episodes (
    submission TEXT NOT NULL REFERENCES submissions(id) ON DELETE CASCADE,
    episode INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    cause TEXT NOT NULL,
    detail TEXT NOT NULL,
    error_line INTEGER,
    score REAL,
    metrics TEXT NOT NULL,
    lab_reruns INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (submission, episode)
);
CREATE TABLE IF NOT EXISTS pseudonyms (
    course TEXT NOT NULL,
    user TEXT NOT NULL,
    pseudonym TEXT NOT NULL,
    PRIMARY KEY (course, user),
    UNIQUE (course, pseudonym COLLATE NOCASE)
);
"""


@dataclass(frozen=True)
class Pending:
    id: str
    assignment: str
    user: str
    filename: str
    source: bytes
    submitted_at: float


class GradingStore:
    def __init__(self, db: LabDatabase) -> None:
        self.db = db
        # The roster is the registry's; created here too, so that a grader's tables
        # can name it whichever process opened the file first.
        db.create(ROSTER_SCHEMA, "course tables")
        db.create(SCHEMA, "grading tables")
        columns = db.columns("episodes")
        assignment_columns = db.columns("assignments")
        with db.transaction() as con:  # a database from before these columns
            if "released_at" not in assignment_columns:  # `wart course release`: NULL until then
                con.execute("ALTER TABLE assignments ADD COLUMN released_at REAL")
            if "real" not in columns:
                con.execute("ALTER TABLE episodes ADD COLUMN real INTEGER NOT NULL DEFAULT 0")
            for added in ("terms", "output"):  # JSON lists: the score by term, printed lines
                if added not in columns:
                    con.execute(
                        f"ALTER TABLE episodes ADD COLUMN {added} TEXT NOT NULL DEFAULT '[]'"
                    )

    # -- assignments (the teacher's CLI)

    def put_assignment(self, a: Assignment, map_text: str) -> bool:
        """Store (or replace) ``a``; True if it is new."""
        if not self.db.rows("SELECT 1 FROM courses WHERE name=?", a.course):
            raise DbError("not_found", f"no course named {a.course}: import its roster first")
        with self.db.transaction() as con:
            new = not con.execute("SELECT 1 FROM assignments WHERE name=?", (a.name,)).fetchone()
            # An update keeps its release: a fixed typo does not hide released results again.
            con.execute(
                "INSERT INTO assignments(name, course, spec, map, updated_at) "
                "VALUES (?, ?, ?, ?, ?) ON CONFLICT(name) DO UPDATE SET course=excluded.course, "
                "spec=excluded.spec, map=excluded.map, updated_at=excluded.updated_at",
                (a.name, a.course, a.to_json(), map_text, time.time()),
            )
        return new

    def release(self, name: str) -> float:
        """Show the assignment's "after_release" results to its students; when (first) released."""
        with self.db.transaction() as con:
            con.execute(
                "UPDATE assignments SET released_at=COALESCE(released_at, ?) WHERE name=?",
                (time.time(), name),
            )
            row = con.execute(
                "SELECT released_at FROM assignments WHERE name=?", (name,)
            ).fetchone()
        if row is None:
            raise DbError("not_found", f"no assignment named {name}")
        return float(row[0])

    def released_at(self, name: str) -> float | None:
        rows = self.db.rows("SELECT released_at FROM assignments WHERE name=?", name)
        return None if not rows or rows[0][0] is None else float(rows[0][0])

    def assignment(self, name: str) -> tuple[Assignment, str]:
        rows = self.db.rows("SELECT spec, map FROM assignments WHERE name=?", name)
        if not rows:
            raise DbError("not_found", f"no assignment named {name}")
        return Assignment.from_json(rows[0][0]), str(rows[0][1])

    def assignments(self, course: str | None = None) -> list[Assignment]:
        rows = self.db.rows(
            "SELECT spec FROM assignments WHERE ?1 IS NULL OR course=?1 ORDER BY name", course
        )
        return [Assignment.from_json(r[0]) for r in rows]

    def assignments_of(self, user: str) -> list[Assignment]:
        """The assignments of every course ``user`` is a member of."""
        rows = self.db.rows(
            "SELECT a.spec FROM assignments a JOIN course_members m ON m.course = a.course "
            "WHERE m.user=? ORDER BY a.course, a.name",
            user,
        )
        return [Assignment.from_json(r[0]) for r in rows]

    def role_in(self, course: str, user: str) -> str | None:
        rows = self.db.rows(
            "SELECT role FROM course_members WHERE course=? AND user=?", course, user
        )
        return str(rows[0][0]) if rows else None

    def display_names(self, course: str) -> dict[str, str]:
        rows = self.db.rows("SELECT user, display_name FROM course_members WHERE course=?", course)
        return {str(u): str(n) for u, n in rows}

    def set_pseudonym(self, course: str, user: str, pseudonym: str) -> None:
        """``user``'s name on the course's leaderboards ("": none); DbError if taken."""
        with self.db.transaction() as con:
            con.execute("DELETE FROM pseudonyms WHERE course=? AND user=?", (course, user))
            if not pseudonym:
                return
            taken = con.execute(
                "SELECT 1 FROM pseudonyms WHERE course=? AND pseudonym=? COLLATE NOCASE",
                (course, pseudonym),
            ).fetchone()
            names = con.execute(
                "SELECT 1 FROM course_members WHERE course=? AND user!=? AND "
                "(user=?3 COLLATE NOCASE OR display_name=?3 COLLATE NOCASE)",
                (course, user, pseudonym),
            ).fetchone()
            if taken or names:
                raise DbError("conflict", f"the name {pseudonym!r} is taken in {course}")
            con.execute(
                "INSERT INTO pseudonyms(course, user, pseudonym) VALUES (?, ?, ?)",
                (course, user, pseudonym),
            )

    def pseudonyms(self, course: str) -> dict[str, str]:
        rows = self.db.rows("SELECT user, pseudonym FROM pseudonyms WHERE course=?", course)
        return {str(u): str(p) for u, p in rows}

    # -- submissions

    def counted_since(self, assignment: str, user: str, since: float) -> int:
        """Graded runs that count against the quota since ``since`` (lab faults do not)."""
        rows = self.db.rows(
            "SELECT COUNT(*) FROM submissions WHERE assignment=? AND user=? AND submitted_at>=? "
            "AND counted=1 AND status!='failed'",
            assignment,
            user,
            since,
        )
        return int(rows[0][0])

    def oldest_counted_since(self, assignment: str, user: str, since: float) -> float | None:
        rows = self.db.rows(
            "SELECT MIN(submitted_at) FROM submissions WHERE assignment=? AND user=? "
            "AND submitted_at>=? AND counted=1 AND status!='failed'",
            assignment,
            user,
            since,
        )
        return None if rows[0][0] is None else float(rows[0][0])

    def add_submission(
        self, assignment: str, user: str, filename: str, source: bytes, late_days: int
    ) -> Pending:
        sub = Pending(
            id=f"s{uuid.uuid4().hex[:16]}",
            assignment=assignment,
            user=user,
            filename=filename,
            source=source,
            submitted_at=time.time(),
        )
        with self.db.transaction() as con:
            con.execute(
                "INSERT INTO submissions(id, assignment, user, submitted_at, filename, source, "
                "status, late_days) VALUES (?, ?, ?, ?, ?, ?, 'queued', ?)",
                (sub.id, assignment, user, sub.submitted_at, filename, source, late_days),
            )
        return sub

    def pending(self) -> list[Pending]:
        """Submissions not graded yet (queued, or running when a grader died), oldest first."""
        rows = self.db.rows(
            "SELECT id, assignment, user, filename, source, submitted_at FROM submissions "
            "WHERE status IN ('queued', 'running') ORDER BY submitted_at"
        )
        return [
            Pending(str(i), str(a), str(u), str(f), bytes(s), float(t)) for i, a, u, f, s, t in rows
        ]

    def set_status(self, sub: str, status: str, message: str = "") -> None:
        with self.db.transaction() as con:
            con.execute(
                "UPDATE submissions SET status=?, message=? WHERE id=?",
                (status, message[:256], sub),
            )

    def finish(
        self,
        sub: str,
        episodes: list[EpisodeResult],
        *,
        status: str,
        counted: bool,
        mean: float | None,
        low: float | None,
        penalty: float,
        message: str,
    ) -> None:
        with self.db.transaction() as con:
            con.execute("DELETE FROM episodes WHERE submission=?", (sub,))
            for e in episodes:
                _insert_episode(con, sub, e)
            con.execute(
                "UPDATE submissions SET status=?, counted=?, mean=?, min=?, penalty=?, "
                "graded_at=?, message=? WHERE id=?",
                (status, int(counted), mean, low, penalty, time.time(), message[:256], sub),
            )

    def add_episode(self, sub: str, e: EpisodeResult) -> None:
        """One episode as it is graded: a grader that dies mid-submission leaves what it had
        (the student reads it; the next start goes on from the next episode)."""
        with self.db.transaction() as con:
            con.execute(
                "DELETE FROM episodes WHERE submission=? AND episode=? AND real=0", (sub, e.episode)
            )
            _insert_episode(con, sub, e)

    def add_real(self, sub: str, e: EpisodeResult, message: str) -> None:
        """The real-robot attempt's row joined to a graded submission, and its message."""
        with self.db.transaction() as con:
            con.execute("DELETE FROM episodes WHERE submission=? AND real=1", (sub,))
            con.execute(
                "INSERT INTO episodes(submission, episode, seed, cause, detail, error_line, "
                "score, metrics, lab_reruns, real) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, 1)",
                (sub, e.episode, e.seed, e.cause, e.detail, e.error_line, e.score,
                 json.dumps(e.metrics), e.lab_reruns),
            )  # fmt: skip
            con.execute("UPDATE submissions SET message=? WHERE id=?", (message[:256], sub))

    def real_pending(self) -> list[Pending]:
        """Graded submissions whose real-robot attempt was queued and has no row yet."""
        rows = self.db.rows(
            "SELECT id, assignment, user, filename, source, submitted_at FROM submissions s "
            "WHERE status='graded' AND message LIKE '%its real-robot attempt is queued on%' "
            "AND NOT EXISTS (SELECT 1 FROM episodes e WHERE e.submission=s.id AND e.real=1) "
            "ORDER BY submitted_at"
        )
        return [Pending(str(i), str(a), str(u), str(f), bytes(s), float(t))
                for i, a, u, f, s, t in rows]  # fmt: skip

    def set_message(self, sub: str, message: str) -> None:
        with self.db.transaction() as con:
            con.execute("UPDATE submissions SET message=? WHERE id=?", (message[:256], sub))

    def real_score(self, sub: str) -> float | None:
        rows = self.db.rows(
            "SELECT score FROM episodes WHERE submission=? AND real=1 AND score IS NOT NULL", sub
        )
        return float(rows[0][0]) if rows else None

    def grader_failures(self, assignment: str) -> tuple[int, str]:
        """How many submissions the teacher's grader function failed, and the latest's message."""
        failed = "assignment=?1 AND message LIKE 'the teacher''s grader failed:%'"
        rows = self.db.rows(
            f"SELECT COUNT(*), (SELECT message FROM submissions WHERE {failed} "
            f"ORDER BY graded_at DESC LIMIT 1) FROM submissions WHERE {failed}",
            assignment,
        )
        count, latest = rows[0] if rows else (0, None)
        return int(count or 0), str(latest or "")

    def submissions(
        self, assignment: str, user: str | None = None, sub: str | None = None
    ) -> list[SubmissionInfo]:
        rows = self.db.rows(
            "SELECT id, assignment, user, status, submitted_at, graded_at, mean, min, late_days, "
            "penalty, counted, message FROM submissions WHERE assignment=?1 "
            "AND (?2 IS NULL OR user=?2) AND (?3 IS NULL OR id=?3) ORDER BY submitted_at",
            assignment,
            user,
            sub,
        )
        out = []
        for i, a, u, st, at, gat, mean, low, late, pen, counted, msg in rows:
            eps = [
                EpisodeResult(
                    episode=int(n),
                    seed=int(seed),
                    cause=cause,
                    detail=str(detail),
                    error_line=line,
                    score=score,
                    metrics=json.loads(m),
                    lab_reruns=int(reruns),
                    real=bool(real),
                    terms=[(str(t), float(v)) for t, v in json.loads(terms)],
                    output=[str(line) for line in json.loads(printed)],
                )
                for n, seed, cause, detail, line, score, m, reruns, real, terms, printed in (
                    self.db.rows(
                        "SELECT episode, seed, cause, detail, error_line, score, metrics, "
                        "lab_reruns, real, terms, output FROM episodes WHERE submission=? "
                        "ORDER BY episode",
                        i,
                    )
                )
            ]
            out.append(
                SubmissionInfo(
                    submission=str(i),
                    assignment=str(a),
                    user=str(u),
                    status=st,
                    submitted_at=float(at),
                    graded_at=gat,
                    mean=mean,
                    min=low,
                    late_days=int(late),
                    penalty=float(pen),
                    counted=bool(counted),
                    message=str(msg),
                    episodes=eps,
                )
            )
        return out

    def best(self, assignment: str, higher: bool) -> list[tuple[str, float, str, float]]:
        """(user, best mean after penalty, submission, its time), one row per student."""
        agg = "MAX" if higher else "MIN"
        rows = self.db.rows(
            f"SELECT user, {agg}(mean - penalty) FROM submissions "
            "WHERE assignment=? AND status='graded' AND mean IS NOT NULL GROUP BY user",
            assignment,
        )
        out = []
        for user, score in rows:
            sub = self.db.rows(
                "SELECT id, submitted_at FROM submissions WHERE assignment=? AND user=? "
                "AND status='graded' AND mean - penalty = ? ORDER BY submitted_at LIMIT 1",
                assignment,
                user,
                score,
            )
            out.append((str(user), float(score), str(sub[0][0]), float(sub[0][1])))
        return out

    def graded(self, assignment: str) -> list[tuple[Pending, float]]:
        """Every graded submission with its score after penalty, oldest first."""
        rows = self.db.rows(
            "SELECT id, assignment, user, filename, source, submitted_at, mean - penalty "
            "FROM submissions WHERE assignment=? AND status='graded' AND mean IS NOT NULL "
            "ORDER BY submitted_at",
            assignment,
        )
        return [
            (Pending(str(i), str(a), str(u), str(f), bytes(s), float(t)), float(score))
            for i, a, u, f, s, t, score in rows
        ]

    def teams(self, course: str) -> dict[str, str]:
        """Each student's team in the course; a student without a team is their own."""
        rows = self.db.rows(
            "SELECT user, team FROM course_members WHERE course=? AND role='student'", course
        )
        return {str(u): str(t) or str(u) for u, t in rows}

    # -- the teacher's view of a class (services/grader/class_view.py)

    def taught_by(self, user: str) -> list[tuple[str, str]]:
        """(course, title) of each course ``user`` teaches."""
        rows = self.db.rows(
            "SELECT c.name, c.title FROM courses c JOIN course_members m ON m.course = c.name "
            "WHERE m.user=? AND m.role='teacher' ORDER BY c.name",
            user,
        )
        return [(str(n), str(t)) for n, t in rows]

    def course_title(self, course: str) -> str | None:
        rows = self.db.rows("SELECT title FROM courses WHERE name=?", course)
        return str(rows[0][0]) if rows else None

    def students(self, course: str) -> list[tuple[str, str, str]]:
        """(user, display name, team) of each student of the course, by user."""
        rows = self.db.rows(
            "SELECT user, display_name, team FROM course_members "
            "WHERE course=? AND role='student' ORDER BY user",
            course,
        )
        return [(str(u), str(n), str(t)) for u, n, t in rows]

    def course_submissions(self, course: str) -> list[CourseSubmission]:
        """Every submission to the course's assignments, oldest first, with the first
        episode of each that did not end well (its cause and detail)."""
        rows = self.db.rows(
            "SELECT s.id, s.assignment, s.user, s.status, s.submitted_at, "
            "CASE WHEN s.mean IS NULL THEN NULL ELSE s.mean - s.penalty END, s.message, "
            "(SELECT e.cause || ': ' || e.detail FROM episodes e WHERE e.submission = s.id "
            " AND e.cause NOT IN ('ok', 'finished') ORDER BY e.episode LIMIT 1) "
            "FROM submissions s JOIN assignments a ON a.name = s.assignment "
            "WHERE a.course=? ORDER BY s.submitted_at",
            course,
        )
        return [
            CourseSubmission(str(i), str(a), str(u), str(st), float(at), sc, str(msg), fail or "")
            for i, a, u, st, at, sc, msg, fail in rows
        ]


def _insert_episode(con: sqlite3.Connection, sub: str, e: EpisodeResult) -> None:
    con.execute(
        "INSERT INTO episodes(submission, episode, seed, cause, detail, error_line, "
        "score, metrics, lab_reruns, real, terms, output) "
        "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
        (
            sub,
            e.episode,
            e.seed,
            e.cause,
            e.detail,
            e.error_line,
            e.score,
            json.dumps(e.metrics),
            e.lab_reruns,
            int(e.real),
            json.dumps(e.terms),
            json.dumps(e.output),
        ),
    )


@dataclass(frozen=True)
class CourseSubmission:
    id: str
    assignment: str
    user: str
    status: str
    submitted_at: float
    score: float | None  # after penalty; None until graded
    message: str
    failed_episode: str  # "cause: detail" of its first episode that did not end well, or ""
