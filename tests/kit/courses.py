"""A course for the grading runs: its name, the reach-the-goal assignment's file, the
course put straight into a registry's database, and a grading lab with its roster."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

from services.grader.assignment import parse_assignment
from services.grader.grading_db import GradingStore
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from tests.kit.agentkit import start_runner, together
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.procs import REPO, Procs, Router, wart

COURSE = "robotics-26"
# A class of one student and its teacher, as `wart users import` reads it.
ROSTER = "user,name,role\nalice,Alice A,student\nida,Ida I,teacher\n"


RULE = '100 * reached("goal") - 5 * collisions() - time_to("goal")'


def assignment_toml(
    name: str,
    *,
    start_x: float = 300,
    goal_x: float = 420,
    goal_radius: float = 60,
    rule: str = RULE,
    sections: str = "",
    **fields: str,
) -> str:
    """The reach-the-goal assignment: from (``start_x``, 500) to a circle at (``goal_x``,
    500); ``fields`` replace its top-level lines and ``sections`` (TOML) follow it."""
    values = {
        "name": f'"{name}"',
        "course": f'"{COURSE}"',
        "map": '"empty"',
        "robot": '"k1"',
        "time_limit": "3.0",
        "episodes": "2",
        "opens": "2026-01-01T00:00:00Z",
        "deadline": "2099-01-01T00:00:00Z",
        "quota": "5",
        **fields,
    }
    head = "\n".join(f"{k} = {v}" for k, v in values.items())
    return (
        f"{head}\n\n"
        f"[[start]]\nx = {start_x:g}\ny = 500\nheading_deg = 0\n\n"
        f'[[zones]]\nid = "goal"\nshape = "circle"\n'
        f"x = {goal_x:g}\ny = 500\nradius = {goal_radius:g}\n\n"
        f'[score]\nname = "points"\nunit = "pts"\norder = "higher"\nrule = \'{rule}\'\n'
        + (f"\n{textwrap.dedent(sections).strip()}\n" if sections else "")
    )


def add_course(db_path: Path, rows: Sequence[RosterRow], assignment: str) -> None:
    """COURSE in the registry's database ``db_path``: its roster ``rows`` and the assignment
    whose TOML is ``assignment`` (its map one of maps/)."""
    db = RegistryDB(db_path)
    CourseStore(db).import_roster(COURSE, list(rows))
    parsed, map_text = parse_assignment(assignment.encode(), "a.toml", REPO / "maps")
    GradingStore(db.database).put_assignment(parsed, map_text)
    db.close()


def import_roster(lab: ProcessLab, roster: str = ROSTER) -> None:
    """``roster`` (CSV, its header first) imported into COURSE in ``lab``'s database by
    ``wart users import``, as a teacher does."""
    path = lab.state.parent / "class.csv"
    path.write_text(roster)
    done = wart("users", "--db", str(lab.db_path), "import", str(path), "--course", COURSE)
    assert done.returncode == 0, done.stderr


def start_grading_lab(router: Router, procs: Procs, tmp: Path, roster: str = ROSTER) -> ProcessLab:
    """A lab on ``router`` that grades: the registry with COURSE's ``roster`` imported, then
    the runner and the grader (together); no engine."""
    lab = make_lab(router, procs, tmp)
    lab.start_registry()
    import_roster(lab, roster)
    together(lambda: start_runner(lab), lab.start_grader)
    return lab
