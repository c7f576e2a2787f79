"""A student watches a competition's ranking change in the page as heats end (issue 36 item 7).

A real lab (router, registry, engine, runner, the agent context ``arena``) and
the grader as processes. alice (team ants) and bob (team zebras) have graded
submissions; alice opens her Course folder and lists her assignments, then the
teacher starts a competition. With no click of hers, the page shows heat 1's
result while heat 2 runs, then the final ranking with each entry's cause.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.grader_client import GraderClient
from services.registry.roster import RosterRow
from tests.browser.test_real_agents import enter_arena
from tests.conftest import needs_sandbox
from tests.kit.courses import add_course, assignment_toml
from tests.kit.reallab import RealLab, real_lab

pytestmark = [
    pytest.mark.integration,
    pytest.mark.timeout(400),
    needs_sandbox,
    pytest.mark.real_lab,
]
REPO = Path(__file__).resolve().parents[2]
GRADING = REPO / "tests" / "integration" / "grading"


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("competelab")), agents=True) as env:
        rows = [
            RosterRow(line=2, user="alice", name="Alice A", team="ants"),
            RosterRow(line=3, user="bob", name="Bob B", team="zebras"),
            RosterRow(line=4, user="ida", name="Ida I", role="teacher"),
        ]
        add_course(env.lab.db_path, rows, assignment_toml("reach-goal", episodes="1", seeds="[4]"))
        env.lab.start_grader()
        yield env


def test_a_student_sees_the_ranking_change_as_heats_end(open_page, lab: RealLab) -> None:
    # Heat 1 is ants (works: a few seconds), heat 2 zebras (loops: caught after ~15 s).
    for user, name in (("alice", "works"), ("bob", "loops")):
        with lab.lab.client(user) as client:
            grader = GraderClient(client)
            sub = grader.submit("reach-goal", (GRADING / f"{name}.py").read_bytes(), f"{name}.py")
            assert grader.wait_graded("reach-goal", sub.submission, 180).status == "graded"

    alice = open_page("alice")
    enter_arena(alice, lab, "alice")
    alice.p.get_by_text("Course", exact=True).first.click()
    alice.click("Refresh assignments")
    alice.wait_text("1 assignment(s) in your courses.")

    with lab.lab.client("ida") as client:
        first = GraderClient(client).run_competition("reach-goal", "final")
    assert [e.team for e in first.entries] == ["ants", "zebras"]

    # Live, with no click: heat 1 ended (its score and cause) while heat 2 runs.
    alice.wait_text("Competition final", timeout=30_000)
    alice.wait_text("heat 2 of 2 running", timeout=60_000)
    alice.p.get_by_role("cell", name="ok: ran its 3 simulated s", exact=True).first.wait_for(
        timeout=10_000
    )
    alice.p.get_by_role("cell", name="99.62", exact=True).first.wait_for(timeout=10_000)
    # Then the end: zebras ranked second with its cause.
    alice.wait_text("finished, 2 heat(s)", timeout=90_000)
    alice.p.get_by_role("cell", name="-3", exact=True).first.wait_for(timeout=10_000)
    alice.wait_text("timeout: the entry's controller: it did not answer in time")
    rows = alice.p.get_by_role("row").all_inner_texts()
    ranked = [r.split("\t")[:2] for r in rows if "ants" in r or "zebras" in r]
    assert [r[1].strip() for r in ranked[-2:]] == ["ants", "zebras"], rows
    alice.p.get_by_text("Competition final").first.scroll_into_view_if_needed()
    alice.screenshot("competition-finished")
