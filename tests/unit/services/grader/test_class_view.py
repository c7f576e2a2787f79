"""The teacher's view of a class, without a lab: a real registry database, the grader's queue."""

from __future__ import annotations

from pathlib import Path

from common.messages import EpisodeResult
from services.grader.assignment import parse_assignment
from services.grader.class_view import class_table
from services.grader.fair_queue import FairQueue
from services.grader.grading_db import GradingStore
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from tests.unit.services.grader.test_grading_rules import GOOD, MAPS

COURSE = "robotics-26"


def episode(cause: str, score: float, detail: str = "") -> EpisodeResult:
    return EpisodeResult(episode=0, seed=1, cause=cause, detail=detail, score=score, metrics={})  # type: ignore[arg-type]


def test_every_student_has_a_row_with_latest_status_queue_place_score_and_last_failure(
    tmp_path: Path,
) -> None:
    db = RegistryDB(tmp_path / "registry.db")
    rows = [
        RosterRow(line=2, user="alice", name="Alice A"),
        RosterRow(line=3, user="bob", name="Bob B", team="red"),
        RosterRow(line=4, user="carol"),
        RosterRow(line=5, user="dora"),
        RosterRow(line=6, user="ida", role="teacher"),
    ]
    CourseStore(db).import_roster(COURSE, rows)
    store = GradingStore(db.database)
    a, map_text = parse_assignment(GOOD, "a.toml", MAPS)
    store.put_assignment(a, map_text)
    queue: FairQueue[str] = FairQueue()

    # alice: graded 80, then a run that raised (graded too: her code's fault), scored -3.
    s1 = store.add_submission(a.name, "alice", "c.py", b"", 0)
    store.finish(s1.id, [episode("ok", 80.0)], status="graded", counted=True,
                 mean=80.0, low=80.0, penalty=0.0, message="")  # fmt: skip
    s2 = store.add_submission(a.name, "alice", "c.py", b"", 0)
    raised = "your controller: line 13: ZeroDivisionError: division by zero"
    store.finish(s2.id, [episode("exception", -3.0, raised)], status="graded", counted=True,
                 mean=-3.0, low=-3.0, penalty=1.0, message="")  # fmt: skip
    # bob: the lab failed his first; his second waits behind carol's in the queue.
    s3 = store.add_submission(a.name, "bob", "c.py", b"", 0)
    store.finish(s3.id, [], status="failed", counted=False, mean=None, low=None, penalty=0.0,
                 message="the lab could not grade it (no runner)")  # fmt: skip
    s4 = store.add_submission(a.name, "carol", "c.py", b"", 0)
    s5 = store.add_submission(a.name, "bob", "c.py", b"", 0)
    queue.put("carol", s4.id)
    queue.put("bob", s5.id)
    # alice's first is being graded again? no: a running one has no place.
    order = [sub for _user, sub in queue.order()]

    table = class_table(COURSE, "Robotics", store.students(COURSE),
                        store.course_submissions(COURSE), order)  # fmt: skip
    by_user = {r.user: r for r in table.rows}
    assert list(by_user) == ["alice", "bob", "carol", "dora"]  # students only, the teacher not
    alice, bob, carol, dora = (by_user[u] for u in ("alice", "bob", "carol", "dora"))
    assert (alice.name, alice.status, alice.submission, alice.submissions) == (
        "Alice A",
        "graded",
        s2.id,
        2,
    )
    assert alice.score == -4.0  # the latest graded, after its penalty
    assert alice.failure == f"exception: {raised}"
    assert alice.queue_place is None
    assert (bob.status, bob.queue_place, bob.team) == ("queued", 2, "red")
    assert bob.failure == "lab: the lab could not grade it (no runner)"
    assert bob.score is None
    assert (carol.status, carol.queue_place, carol.failure) == ("queued", 1, "")
    assert (dora.submission, dora.status, dora.submissions) == (None, None, 0)

    assert store.taught_by("ida") == [(COURSE, COURSE)]
    assert store.taught_by("alice") == []
    db.close()


def test_the_queue_order_is_the_order_jobs_are_taken() -> None:
    queue: FairQueue[str] = FairQueue()
    for user, job in [("a", "a1"), ("a", "a2"), ("a", "a3"), ("b", "b1"), ("c", "c1"),
                      ("c", "c2")]:  # fmt: skip
        queue.put(user, job)
    queue.put_first("b", "rerun")
    said = queue.order()
    taken = [queue.get(0.1) for _ in range(len(said))]
    assert said == taken
    assert [job for _u, job in said] == ["rerun", "a1", "b1", "c1", "a2", "c2", "a3"]


def test_a_published_change_carries_no_score_and_no_name() -> None:
    """Everyone in the realm may hear it: what each may see, each page asks the grader for
    (a leaderboard hidden until the deadline stays there for students)."""
    from common.messages import GradingChanged

    assert set(GradingChanged.__struct_fields__) == {
        "course", "assignment", "submission", "status", "at", "v",
    }  # fmt: skip
