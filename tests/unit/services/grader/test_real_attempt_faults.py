"""A real-robot attempt's lab faults are queued again, free, then said (issue 36, item 3)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any, ClassVar

import pytest

from common.lab_errors import LabError
from common.messages import ControlQueued, EpisodeResult, RequestStatus
from services.grader import real_attempt
from services.grader.assignment import parse_assignment
from services.grader.grading_db import GradingStore, Pending
from services.grader.real_attempt import REAL_RETRIES, RealAttempt
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow

MAPS = Path(__file__).resolve().parents[4] / "maps"
TOML = b"""
name = "r"
course = "c"
map = "empty"
robot = "k1"
time_limit = 2
deadline = 2099-01-01T00:00:00Z
[[start]]
x = 300
y = 500
[score]
rule = 'distance()'
[real]
arena = "arena"
robot = "k1"
"""


class FakeArena:
    """An agent context whose robot leaves the world during every run (its bridge died)."""

    queued: ClassVar[list[str]] = []
    joins = 0

    def __init__(self, client: object, ctx: str) -> None:
        self.ctx = ctx

    def join(self) -> FakeArena:
        FakeArena.joins += 1
        return self

    def leave(self) -> None:
        pass

    def queue(self, agent: str, mode: str, **_: Any) -> ControlQueued:
        FakeArena.queued.append(f"{agent}:{mode}")
        return ControlQueued(request_id=f"r{len(self.queued)}", agent=agent, position=0,
                             start_eta=0.0, slot_seconds=1.0)  # fmt: skip

    def wait_status(self, request_id: str, *_: Any, **__: Any) -> RequestStatus:
        return RequestStatus(request_id=request_id, agent="k1", user="grader-grader",
                             status="cancelled", reason="k1 left the world")  # fmt: skip


def test_a_robot_that_leaves_the_world_is_the_labs_fault_and_queued_again(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    a, map_text = parse_assignment(TOML, "r.toml", MAPS)
    monkeypatch.setattr(real_attempt, "AgentClient", FakeArena)
    monkeypatch.setattr(real_attempt.time, "sleep", lambda s: None)
    stop = threading.Event()
    stop.wait = lambda timeout=None: False  # type: ignore[method-assign]  # no pauses here
    logins: list[int] = []
    attempt = RealAttempt(object(), lambda a, d: ({}, "", None), stop, lambda: logins.append(1))  # type: ignore[arg-type]
    sub = Pending("s1", "r", "alice", "works.py", b"x", 0.0)
    result = attempt.run(sub, a, map_text)
    assert FakeArena.queued == ["k1:deploy"] * (REAL_RETRIES + 1)  # queued again, free
    assert len(logins) == REAL_RETRIES + 1  # a fresh session (and its grants) each time
    assert result.real and result.cause == "lab" and result.score is None
    assert result.lab_reruns == REAL_RETRIES
    assert result.detail == "the real run was cancelled: k1 left the world"


def test_an_arena_that_does_not_answer_is_the_labs_fault(monkeypatch: pytest.MonkeyPatch) -> None:
    a, map_text = parse_assignment(TOML, "r.toml", MAPS)

    class Silent(FakeArena):
        def join(self) -> FakeArena:
            raise LabError("no agent context arena answered")

    monkeypatch.setattr(real_attempt, "AgentClient", Silent)
    stop = threading.Event()
    stop.wait = lambda timeout=None: False  # type: ignore[method-assign]
    attempt = RealAttempt(object(), lambda a, d: ({}, "", None), stop)  # type: ignore[arg-type]
    result = attempt.run(Pending("s1", "r", "alice", "w.py", b"x", 0.0), a, map_text)
    assert result.cause == "lab" and result.lab_reruns == REAL_RETRIES
    assert result.detail.startswith("the real arena arena did not answer")


def test_a_real_attempt_queued_when_the_grader_stopped_is_found_at_its_start(
    tmp_path: Path,
) -> None:
    db = RegistryDB(tmp_path / "registry.db")
    try:
        CourseStore(db).import_roster("c", [RosterRow(line=2, user="alice", name="Alice")])
        store = GradingStore(db.database)
        a, map_text = parse_assignment(TOML, "r.toml", MAPS)
        store.put_assignment(a, map_text)
        subs = [store.add_submission("r", "alice", "w.py", b"x", 0) for _ in range(3)]
        for sub in subs:
            store.finish(sub.id, [], status="graded", counted=True, mean=1.0, low=1.0,
                         penalty=0.0, message="points: mean 1")  # fmt: skip
        for sub in subs[:2]:
            store.set_message(sub.id, "points: mean 1; its real-robot attempt is queued on arena")
        done = EpisodeResult(episode=1, seed=0, cause="ok", score=2.0, real=True)
        store.add_real(subs[0].id, done, "points: mean 1; real-robot attempt: points 2")
        assert [p.id for p in store.real_pending()] == [subs[1].id]  # queued, never run
        assert store.real_score(subs[0].id) == 2.0
        assert [e.real for e in store.submissions("r", sub=subs[0].id)[0].episodes] == [True]
    finally:
        db.close()
