"""A class from a roster file: checked whole, imported in one go, again without change."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from services.registry import accounts_db, courses_db
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import MAX_BYTES, RosterError, parse_roster

CLASS = b"user,name,role,team\nana,Ana Lima,student,red\nbob,Bob,student,red\ncat,Cat,teacher,\n"


@pytest.fixture
def store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> CourseStore:
    # argon2id at full cost is what the registry does; a cheap stand-in keeps this test fast
    monkeypatch.setattr(courses_db, "hash_password", lambda pw: b"hash-of-" + pw.encode())
    db = RegistryDB(tmp_path / "registry.db")
    db.add_user("ana", ["student"], password="ana-old-password")  # she has an account already
    return CourseStore(db)


def test_a_roster_is_read_in_any_column_order_case_and_separator() -> None:
    rows = parse_roster(b"\xef\xbb\xbfTeam;Role;USER\nred;teacher;cat\n\n;;dan\n")
    assert [(r.user, r.role, r.team, r.line) for r in rows] == [
        ("cat", "teacher", "red", 2),
        ("dan", "student", "", 4),
    ]


@pytest.mark.parametrize(
    ("raw", "said"),
    [
        (b"usr,nom\nana,x\n", "line 1: no 'user' column (the header has: usr, nom)"),
        (b"user,grade\nana,3\n", "unknown column grade; the columns are user, name, email"),
        (b"user,user\nana,ana\n", "line 1: column user twice"),
        (b"user,role\nana,professor\n", "line 2: role 'professor' for ana: one of student"),
        (b"user\nana\nbob\nana\n", "line 4: user ana again (first on line 2)"),
        (b"user\nana\nANA\n", "line 3: user ANA again (first on line 2)"),
        (b"user\nregistry\n", "line 2: the name registry is reserved"),
        (b"user\nAna Maria\n", "line 2: user 'Ana Maria' is not a valid name"),
        (b"user,team\nana\n", "line 2: 1 cells for 2 columns"),
        (b"user\nana\nb\xe9a\n", "line 3: not UTF-8 text"),
        (b"", "the file is empty"),
        (b"user\n", "the file names nobody"),
        (b"user\n" + b"a" * MAX_BYTES, "at most 1048576 (1 MiB)"),
    ],
)
def test_a_bad_roster_is_refused_with_its_line(raw: bytes, said: str) -> None:
    with pytest.raises(RosterError) as caught:
        parse_roster(raw)
    assert any(said in p for p in caught.value.problems), caught.value.problems


def test_every_problem_of_a_file_is_said_at_once() -> None:
    with pytest.raises(RosterError) as caught:
        parse_roster(b"user,role\nana,boss\nAna Maria,student\nana,student\nbob,student\n")
    assert len(caught.value.problems) == 2  # line 2 and line 3; line 4's ana is new after all


def test_import_makes_and_matches_accounts_and_again_changes_nothing(store: CourseStore) -> None:
    first = store.import_roster("rob26", parse_roster(CLASS), title="Robotics 26")
    assert first.created_course
    assert first.new_accounts == ["bob", "cat"] and first.joined == ["ana"]
    assert sorted(first.passwords) == ["bob", "cat"]  # ana keeps her own password
    assert all(len(p) == courses_db.FIRST_PASSWORD_LENGTH for p in first.passwords.values())
    assert store.db.check_credential("ana", "password", "ana-old-password")
    assert [g for _, g in store.db.grants_of("cat")] == ["role:instructor"]
    assert store.courses() == [("rob26", "Robotics 26", 3)]
    again = store.import_roster("rob26", parse_roster(CLASS))
    assert (again.new_accounts, again.joined, again.changed) == ([], [], [])
    assert sorted(again.unchanged) == ["ana", "bob", "cat"] and again.passwords == {}
    assert "  unchanged: 3" in again.lines()


def test_a_new_roster_says_what_changed_and_keeps_or_removes_the_missing(
    store: CourseStore,
) -> None:
    store.import_roster("rob26", parse_roster(CLASS))
    moved = parse_roster(b"user,team\nana,blue\ndan,blue\n")
    report = store.import_roster("rob26", moved)
    assert report.changed == ["ana"] and report.new_accounts == ["dan"]
    assert report.missing == ["bob", "cat"]
    assert {m.user for m in store.members("rob26")} == {"ana", "bob", "cat", "dan"}
    report = store.import_roster("rob26", moved, remove_missing=True)
    assert report.removed == ["bob", "cat"]
    assert {m.user for m in store.members("rob26")} == {"ana", "dan"}
    assert store.db.user_exists("bob")  # out of the course, not out of the lab


def test_an_import_that_fails_halfway_writes_nothing(
    store: CourseStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    made: list[str] = []
    real = CourseStore._account

    def fail_on_cat(con, row, hashes, report, now):  # type: ignore[no-untyped-def]
        if row.user == "cat":
            raise accounts_db.DbError("internal", "the disk is full")
        made.append(row.user)
        real(con, row, hashes, report, now)

    monkeypatch.setattr(CourseStore, "_account", staticmethod(fail_on_cat))
    with pytest.raises(accounts_db.DbError, match="the disk is full"):
        store.import_roster("rob26", parse_roster(CLASS))
    assert made == ["ana", "bob"]  # it got that far ...
    assert not store.db.user_exists("bob")  # ... and none of it stayed
    assert store.courses() == []


def test_an_account_beside_one_that_differs_only_by_case_or_a_reserved_name_is_refused(
    store: CourseStore,
) -> None:
    for name, said in (("ANA", "user ana already exists (the same but for case)"),
                       ("Registry", "the name Registry is reserved")):  # fmt: skip
        with pytest.raises(accounts_db.DbError, match=re.escape(said)):
            store.db.add_user(name, ["student"], password="a long password")
