"""A banned student's submissions that wait in the grader's queue are never graded, with
real processes: router, registry, runner, grader."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.client.grader_client import GraderClient
from services.grader.bans import BANNED
from services.grader.service import WORKERS
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.integration.test_grading import add_assignment, source
from tests.kit.courses import start_grading_lab
from tests.kit.lab import ProcessLab

pytestmark = [pytest.mark.timeout(300), needs_sandbox]


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    roster = "user,name,role\nbob,Bob B,student\nida,Ida I,teacher\n"
    return start_grading_lab(router, procs, tmp_path, roster)


def test_a_banned_students_queued_submissions_are_not_graded(
    lab: ProcessLab, tmp_path: Path
) -> None:
    add_assignment(lab, tmp_path, "long", time_limit="8.0", episodes="1", seeds="[1]")
    with lab.client("bob") as bob:
        grader = GraderClient(bob)
        handed = [grader.submit("long", source("loops"), "loops.py").submission for _ in range(4)]
        wait_for(
            lambda: any(s.status == "running" for s in grader.submissions("long")), 60, "running"
        )
    with lab.client("admin") as admin:
        admin.ban("bob", "handed in someone else's code")
    with lab.client("ida") as ida:
        teacher = GraderClient(ida)

        def settled() -> object:
            found = teacher.submissions("long", user="bob")
            return all(s.status in ("graded", "failed") for s in found) and found

        found = wait_for(settled, 120, "every submission of bob settled")
    assert isinstance(found, list) and {s.submission for s in found} == set(handed)
    dropped = [s for s in found if s.message == BANNED]
    assert len(dropped) >= len(handed) - WORKERS  # the queued ones: only running ones end
    assert all(s.status == "failed" and not s.counted for s in dropped)
