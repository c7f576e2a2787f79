"""A submission the grader itself fails on is queued again at the head, then failed, never lost.

Before, it was marked "queued" with no place in the queue and waited for the
grader's next start; one that always fails must not loop either.
"""

from __future__ import annotations

import logging
from types import SimpleNamespace
from typing import Any

from services.grader.fair_queue import FairQueue
from services.grader.grading_db import Pending
from services.grader.service import GRADER_TRIES, GraderService


class Store:
    def __init__(self) -> None:
        self.status: dict[str, tuple[str, str]] = {}
        self.finished: dict[str, dict[str, Any]] = {}

    def set_status(self, sub: str, status: str, message: str = "") -> None:
        self.status[sub] = (status, message)

    def finish(self, sub: str, episodes: list[Any], **fields: Any) -> None:
        self.finished[sub] = fields


def grader() -> SimpleNamespace:
    g = SimpleNamespace(
        store=Store(),
        queue=FairQueue[Pending](),
        log=logging.getLogger("test-grader"),
        _grader_failures={},
        changes=[],
    )
    g._changed = lambda sub, status, course=None: g.changes.append((sub.id, status))
    g._fail_uncounted = lambda sub, episodes, message: GraderService._fail_uncounted(
        g, sub, episodes, message
    )
    return g


def pending(sid: str, user: str) -> Pending:
    return Pending(sid, "reach-goal", user, "c.py", b"", 0.0)


def test_a_grader_failure_requeues_the_submission_ahead_of_others() -> None:
    g = grader()
    g.queue.put("bob", pending("s2", "bob"))
    GraderService._grader_failed(g, pending("s1", "alice"), RuntimeError("disk full"))
    assert g.store.status["s1"] == ("queued", "the grader failed: queued again")
    assert g.changes == [("s1", "queued")]
    first = g.queue.get(timeout=1)
    assert first is not None and first[1].id == "s1"  # before bob's, which waited less


def test_a_submission_the_grader_always_fails_on_ends_failed_and_not_counted() -> None:
    g = grader()
    sub = pending("s1", "alice")
    for _ in range(GRADER_TRIES):
        GraderService._grader_failed(g, sub, RuntimeError("a broken assignment row"))
    done = g.store.finished["s1"]
    assert done["status"] == "failed" and done["counted"] is False
    assert "the grader failed 3 times: a broken assignment row" in done["message"]
    assert "not counted against your quota" in done["message"]
    assert g.changes[-1] == ("s1", "failed")
    # queued again twice, then no more: nothing loops
    assert len(g.queue.order()) == GRADER_TRIES - 1
    assert g._grader_failures == {}
