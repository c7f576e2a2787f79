"""A student's Course folder in the page: her assignment, the editor's code handed in, her score,
the leaderboard (issue 36).

A real lab (router, registry, engine, runner, the agent context ``arena``) and
the grader as processes; the course imported and an assignment added in the
registry's database as the teacher's tools do. alice opens the arena, her
Course folder lists the assignment, she submits the file open in her editor,
and the page shows the graded score and her name on the leaderboard.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from services.grader.assignment import parse_assignment
from services.grader.grading_db import GradingStore
from services.lab import wiring
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from services.runner.sandbox import sandbox_problem
from tests.browser.conftest import wait_until
from tests.browser.reallab import RealLab, real_lab
from tests.browser.test_real_agents import choose, enter_arena
from tests.integration.test_grading import assignment_toml
from viewers.web.app import WebViewer
from viewers.web.inputs import set_value

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.timeout(300)]
REPO = Path(__file__).resolve().parents[2]
WORKS = (REPO / "tests" / "integration" / "grading" / "works.py").read_text()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    problem = sandbox_problem()
    if problem:
        pytest.skip(f"the runner cannot sandbox uploads here: {problem}")
    with real_lab(Path(tmp_path_factory.mktemp("courselab")), agents=True) as env:
        db = RegistryDB(env.lab.db_path)
        rows = [RosterRow(line=2, user="alice", name="Alice A"), RosterRow(line=3, user="bob")]
        CourseStore(db).import_roster("robotics-26", rows)
        text = assignment_toml("reach-goal", episodes="1", seeds="[4]")
        assignment, map_text = parse_assignment(text.encode(), "a.toml", REPO / "maps")
        GradingStore(db).put_assignment(assignment, map_text)
        db.close()
        env.lab.account(wiring.service_account("grader", "grader"))
        env.lab.start(wiring.grader_spec(env.lab.wiring()), name="grader")
        yield env


@pytest.fixture
def viewer(lab: RealLab) -> WebViewer:
    return lab.viewer


def test_a_student_submits_the_editors_code_and_sees_her_score(open_page, lab: RealLab) -> None:
    alice = open_page("alice")
    panel = enter_arena(alice, lab, "alice")
    course, workbench = panel.course, panel.workbench
    assert course is not None and workbench is not None
    # What she wrote in the editor (set on the server: the page's editor shows it).
    set_value(workbench.name, "reach.py")
    set_value(workbench.code, WORKS)
    alice.p.get_by_text("Course", exact=True).first.click()
    alice.click("Refresh assignments")
    alice.wait_text("1 assignment(s) in your courses.")
    choose(alice, "Assignment", "reach-goal")
    alice.wait_text("1 episodes of 3 simulated s")
    alice.click("Submit the editor's code")
    alice.wait_text("place 1 in the queue; 1 of 5 graded runs in the last 24 h")

    def graded() -> bool:
        alice.click("My scores")
        return any(s.status == "graded" for s in course.show_scores())

    wait_until(graded, 120, what="alice's submission graded")
    alice.p.get_by_role("cell", name="graded", exact=True).first.wait_for(timeout=10_000)
    alice.p.get_by_role("cell", name="99.62", exact=True).first.wait_for(timeout=10_000)
    alice.click("Leaderboard")
    alice.p.get_by_role("cell", name="Alice A", exact=True).first.wait_for(timeout=10_000)
