"""The registry's term tables: bans with an end, an audit trail nobody edits; login sources."""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path

import pytest

from common.messages import AuditQuery
from services.registry.accounts_db import DbError, RegistryDB
from services.registry.audit_db import Action, TermStore
from services.registry.throttle import LoginThrottle, query_source, vouched_source


@pytest.fixture
def store(tmp_path: Path) -> TermStore:
    db = RegistryDB(tmp_path / "registry.db")
    db.add_user("bob", ["student"], public_key=b"\x01" * 32)
    return TermStore(db)


def test_a_ban_has_a_reason_and_an_end_and_lapses_by_itself(store: TermStore) -> None:
    now = time.time()
    ban = store.ban("bob", "spam", "admin", now + 60)
    assert store.ban_of("bob") == ban and ban.until == now + 60
    assert store.ban_of("bob", now=now + 61) is None  # past its end
    assert store.lift("bob") == ban and store.ban_of("bob") is None
    for bad in (now - 1, float("inf"), float("nan")):
        with pytest.raises(DbError):
            store.ban("bob", "x", "admin", bad)
    with pytest.raises(DbError, match="no user named nobody"):
        store.ban("nobody", "x", "admin", None)


def test_the_trail_is_appended_filtered_paged_and_never_edited(
    store: TermStore, tmp_path: Path
) -> None:
    for i in range(5):
        store.record(Action("admin", "kick", f"user{i}", "ok", f"reason {i}", "zenoh:abc"))
    store.record(Action("bob", "grant", "bob", "refused", "not allowed"))
    entries, more = store.entries(AuditQuery(limit=3))
    assert [e.target for e in entries] == ["bob", "user4", "user3"] and more
    older, more = store.entries(AuditQuery(before_id=entries[-1].id, limit=10))
    assert [e.target for e in older] == ["user2", "user1", "user0"] and not more
    assert {e.actor for e in store.entries(AuditQuery(outcome="refused"))[0]} == {"bob"}
    assert [e.target for e in store.entries(AuditQuery(target="user3"))[0]] == ["user3"]
    assert not store.entries(AuditQuery(since=time.time() + 10))[0]
    raw = sqlite3.connect(tmp_path / "registry.db")
    for sql in ("UPDATE audit SET actor='x'", "DELETE FROM audit"):
        with pytest.raises(sqlite3.DatabaseError, match="append-only"):
            raw.execute(sql)
    # A row a hand broke (an actor that is no name) is shown, not trusted.
    raw.execute(
        "INSERT INTO audit(at, actor, action, target, outcome, detail, source, reporter) "
        "VALUES (1.0, 'not a name!', 'kick', 't', 'ok', '', '', 'registry')"
    )
    raw.commit()
    assert store.entries(AuditQuery(limit=1))[0][0].actor == "unknown"


def test_a_source_is_the_session_or_a_vouched_address_never_via() -> None:
    throttle = LoginThrottle()
    source = query_source("abc")
    now = time.time()
    for _ in range(3):
        throttle.check("alice", source, now)
        throttle.failed("alice", source, now)
    with pytest.raises(Exception, match="too many failed logins"):
        throttle.check("alice", source, now)
    throttle.check("alice", query_source("def"), now)  # another session: checked
    throttle.check("alice", vouched_source("viewer-web", "10.0.0.2"), now)
    assert query_source(None) == "zenoh:undeclared"
