"""A real lab with a course in it: students alice, bob and carol, teacher ida, one assignment.

The lab of tests/kit/reallab.py with agents (engine, runner, the arena context), the
course's roster imported into the registry's database, the reach-the-goal assignment
stored for the grader, and the grader started.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from services.grader.assignment import parse_assignment
from services.grader.grading_db import GradingStore
from services.lab import wiring
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from tests.kit.courses import COURSE, assignment_toml
from tests.kit.reallab import RealLab, real_lab

REPO = Path(__file__).resolve().parents[2]
ASSIGNMENT = "reach-goal"


@contextmanager
def course_lab(tmp: Path, slot: float = 300.0) -> Iterator[RealLab]:
    with real_lab(tmp, agents=True, slot=slot) as env:
        db = RegistryDB(env.lab.db_path)
        rows = [
            RosterRow(line=2, user="alice", name="Alice A"),
            RosterRow(line=3, user="bob"),
            RosterRow(line=4, user="carol"),
            RosterRow(line=5, user="ida", role="teacher"),
        ]
        CourseStore(db).import_roster(COURSE, rows)
        text = assignment_toml(ASSIGNMENT, episodes="1", seeds="[4]")
        assignment, map_text = parse_assignment(text.encode(), "a.toml", REPO / "maps")
        GradingStore(db.database).put_assignment(assignment, map_text)
        db.close()
        env.lab.account(wiring.service_account("grader", "grader"))
        env.lab.start(wiring.grader_spec(env.lab.wiring()), name="grader")
        yield env
