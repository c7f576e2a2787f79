"""The registry database's term tables: bans and the audit trail.

Kept beside accounts_db.py (same SQLite file, same connection and lock). The
audit table is append-only: triggers refuse every UPDATE and DELETE on it, so
neither a bug here nor a later tool can rewrite what happened. A ban row goes
when the ban is lifted; the lifting itself is an audit line.

Refusals cannot bury the trail: the first refusal of one kind (reporter, actor,
action) in a minute is a line at once, and the rest of that minute are counted
and written as one line, "N more refused in the minute from 10:42 UTC (the last:
...)", when the minute is over, the trail is read or the registry stops (a
registry killed meanwhile loses that count, never the first line). A service's
report is appended once: its signature's digest is kept (``audit_reports``, past a
restart) for REPORT_MEMORY_S, longer than a sealed message stays fresh.
"""

from __future__ import annotations

import hashlib
import logging
import math
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime

import msgspec

from common.keys import is_ident
from common.messages import MAX_AUDIT_PAGE, AuditEntry, AuditQuery, BanInfo, MessageError
from services.registry.accounts_db import DbError, RegistryDB

log = logging.getLogger("wart.registry.audit")

SCHEMA = """
CREATE TABLE IF NOT EXISTS bans (
    user TEXT PRIMARY KEY REFERENCES users(name) ON DELETE CASCADE,
    reason TEXT NOT NULL,
    by_user TEXT NOT NULL,
    at REAL NOT NULL,
    until REAL
);
CREATE TABLE IF NOT EXISTS audit (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    at REAL NOT NULL,
    actor TEXT NOT NULL,
    action TEXT NOT NULL,
    target TEXT NOT NULL,
    outcome TEXT NOT NULL,
    detail TEXT NOT NULL,
    source TEXT NOT NULL,
    reporter TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS audit_at ON audit(at);
CREATE TABLE IF NOT EXISTS audit_reports (digest BLOB PRIMARY KEY, until REAL NOT NULL);
CREATE TRIGGER IF NOT EXISTS audit_append_only_update BEFORE UPDATE ON audit
BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
CREATE TRIGGER IF NOT EXISTS audit_append_only_delete BEFORE DELETE ON audit
BEGIN SELECT RAISE(ABORT, 'the audit trail is append-only'); END;
"""

TEXT_MAX = 256  # AuditEntry's ShortText: longer words are cut, never refused
REPORT_MEMORY_S = 600.0  # a report's digest is kept this long (sealed ones are fresh ±30 s)


@dataclass(frozen=True)
class Action:
    """One line to append: who did what on what, from where, and how it ended."""

    actor: str
    action: str
    target: str
    outcome: str  # "ok" or "refused"
    detail: str = ""
    source: str = ""
    reporter: str = "registry"
    at: float | None = None


@dataclass
class _Tally:
    """Refusals of one kind in one minute after its first line: how many, the last."""

    last: Action
    more: int = 0
    minute: int = 0


class TermStore:
    """Bans and the audit trail in the registry's database."""

    def __init__(self, db: RegistryDB) -> None:
        self.db = db
        db.database.create(SCHEMA, "ban and audit tables")
        self._tally: dict[tuple[str, str, str, int], _Tally] = {}
        self._tally_lock = threading.Lock()

    # -- bans

    def ban(self, user: str, reason: str, by: str, until: float | None) -> BanInfo:
        now = time.time()
        if until is not None and not math.isfinite(until):
            raise DbError("bad_request", "a ban's end must be a time (or none: until lifted)")
        if until is not None and until <= now:
            raise DbError("bad_request", "a ban must end in the future (or never)")
        with self.db._tx() as con:
            if not con.execute("SELECT 1 FROM users WHERE name=?", (user,)).fetchone():
                raise DbError("not_found", f"no user named {user}")
            con.execute(
                "INSERT OR REPLACE INTO bans(user, reason, by_user, at, until) "
                "VALUES (?, ?, ?, ?, ?)",
                (user, reason, by, now, until),
            )
        return BanInfo(reason=reason[:TEXT_MAX], by=by, at=now, until=until)

    def lift(self, user: str) -> BanInfo | None:
        """Lift the user's ban; the ban that was in force (None: there was none)."""
        ban = self.ban_of(user)
        with self.db._tx() as con:
            con.execute("DELETE FROM bans WHERE user=?", (user,))
        return ban

    def ban_of(self, user: str, now: float | None = None) -> BanInfo | None:
        """The ban in force on ``user`` (an ended one is not: it lapses by itself)."""
        now = time.time() if now is None else now
        rows = self.db._rows("SELECT reason, by_user, at, until FROM bans WHERE user=?", user)
        if not rows:
            return None
        reason, by, at, until = rows[0]
        if until is not None and float(until) <= now:
            return None
        if not is_ident(str(by)):
            by = "unknown"
        return BanInfo(
            reason=str(reason)[:TEXT_MAX],
            by=str(by),
            at=float(at),
            until=None if until is None else float(until),
        )

    # -- the audit trail

    def record(self, entry: Action) -> int:
        """Append one line; its id (0: a refusal counted into its minute's line)."""
        at = time.time() if entry.at is None else entry.at
        self.flush(before=time.time())
        if entry.outcome == "refused":
            minute = int(at // 60)
            key = (entry.reporter, entry.actor, entry.action, minute)
            with self._tally_lock:
                tally = self._tally.get(key)
                if tally is not None:
                    tally.more += 1
                    tally.last = entry
                    return 0
                self._tally[key] = _Tally(entry, 0, minute)
        return self._append(entry, at)

    def flush(self, before: float | None = None) -> int:
        """Write the refusals counted in minutes ended by ``before`` (None: all); how many."""
        due: list[tuple[_Tally, int]] = []
        with self._tally_lock:
            for key, tally in list(self._tally.items()):
                ended = before is None or tally.minute < int(before // 60)
                if tally.more and (before is None or ended):
                    due.append((tally, tally.more))
                    tally.more = 0
                if ended and before is not None:
                    del self._tally[key]
        for tally, more in due:
            last = tally.last
            start = datetime.fromtimestamp(tally.minute * 60, UTC).strftime("%H:%M")
            words = f"{more} more refused in the minute from {start} UTC (the last: {last.detail})"
            summary = Action(
                last.actor, last.action, last.target, "refused", words, last.source, last.reporter
            )
            self._append(summary, time.time())
        return len(due)

    def first_report(self, signature: bytes, now: float) -> bool:
        """Whether a service's report with this signature is new (then remembered)."""
        digest = hashlib.blake2b(signature, digest_size=16).digest()
        with self.db._tx() as con:
            con.execute("DELETE FROM audit_reports WHERE until < ?", (now,))
            cur = con.execute(
                "INSERT OR IGNORE INTO audit_reports(digest, until) VALUES (?, ?)",
                (digest, now + REPORT_MEMORY_S),
            )
            return bool(cur.rowcount)

    def _append(self, entry: Action, at: float) -> int:
        row = (
            at,
            entry.actor[:64],
            entry.action[:40],
            entry.target[:TEXT_MAX],
            entry.outcome,
            entry.detail[:TEXT_MAX],
            entry.source[:TEXT_MAX],
            entry.reporter[:64],
        )
        with self.db._tx() as con:
            cur = con.execute(
                "INSERT INTO audit(at, actor, action, target, outcome, detail, source, reporter) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                row,
            )
            return int(cur.lastrowid or 0)

    def entries(self, query: AuditQuery) -> tuple[list[AuditEntry], bool]:
        """The lines matching ``query``, newest first, and whether older ones match too."""
        self.flush()  # what was counted so far shows
        where: list[str] = ["1=1"]
        args: list[object] = []
        for column, value in (
            ("actor", query.actor),
            ("action", query.action),
            ("outcome", query.outcome),
        ):
            if value:
                where.append(f"{column}=?")
                args.append(value)
        if query.target:
            where.append("instr(target, ?) > 0")
            args.append(query.target)
        if query.since is not None:
            where.append("at >= ?")
            args.append(query.since)
        if query.until is not None:
            where.append("at <= ?")
            args.append(query.until)
        if query.before_id is not None:
            where.append("id < ?")
            args.append(query.before_id)
        limit = min(query.limit, MAX_AUDIT_PAGE)
        rows = self.db._rows(
            "SELECT id, at, actor, action, target, outcome, detail, source, reporter FROM audit "
            f"WHERE {' AND '.join(where)} ORDER BY id DESC LIMIT ?",
            *args,
            limit + 1,
        )
        out = []
        for row in rows[:limit]:
            try:
                out.append(_entry(row))
            except (MessageError, TypeError, ValueError) as exc:
                log.warning("skipping a malformed audit line %r: %s", row[0], exc)
        return out, len(rows) > limit


def _entry(row: tuple) -> AuditEntry:
    ident, at, actor, action, target, outcome, detail, source, reporter = row
    entry = AuditEntry(
        id=int(ident),
        at=float(at),
        actor=str(actor) if is_ident(str(actor)) else "unknown",
        action=str(action),
        target=str(target),
        outcome=outcome,
        detail=str(detail),
        source=str(source),
        reporter=str(reporter) if is_ident(str(reporter)) else "unknown",
    )
    # A hand-edited row could break the wire constraints: check them as a decoder would.
    try:
        return msgspec.convert(msgspec.to_builtins(entry), AuditEntry)
    except msgspec.ValidationError as exc:
        raise ValueError(str(exc)) from None
