"""A real lab with a course in it: students alice, bob and carol, teacher ida, one assignment.

The lab of tests/kit/reallab.py with agents (engine, runner, the arena context), the
course's roster imported into the registry's database, the reach-the-goal assignment
stored for the grader, and the grader started.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from services.registry.roster import RosterRow
from tests.kit.courses import add_course, assignment_toml
from tests.kit.reallab import RealLab, real_lab

REPO = Path(__file__).resolve().parents[2]
ASSIGNMENT = "reach-goal"


@contextmanager
def course_lab(tmp: Path, slot: float = 300.0) -> Iterator[RealLab]:
    with real_lab(tmp, agents=True, slot=slot) as env:
        rows = [
            RosterRow(line=2, user="alice", name="Alice A"),
            RosterRow(line=3, user="bob"),
            RosterRow(line=4, user="carol"),
            RosterRow(line=5, user="ida", role="teacher"),
        ]
        add_course(env.lab.db_path, rows, assignment_toml(ASSIGNMENT, episodes="1", seeds="[4]"))
        env.lab.start_grader()
        yield env
