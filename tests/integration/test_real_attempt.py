"""A submission's real-robot attempt (issue 36, item 3), with real processes: router,
registry, runner, grader, the bridge and an agent context on the Khepera emulator over a
pseudo-terminal (the real serial protocol).

The simulated episodes pass, then the grader queues the file on the real arena's robot
like a student's run (the context's queue, slot and lease, the runner's sandbox, the
bridge); the context records it, the grader scores it from the recording (the teacher's
grader function on a runner, as in simulation) and joins it to the same submission: a
"real" row, and the leaderboard's real column. An assignment whose real arena is not in
the lab is refused at submission, nothing written.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.client.agent_client import AgentClient
from common.client.grader_client import GraderClient
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import EpisodeResult, SubmissionInfo
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.simbody import SimBody
from services.lab import wiring
from tests.conftest import REPO, Procs, Router, needs_sandbox, wait_for
from tests.integration.test_grader_function import course
from tests.integration.test_grading import source, wart
from tests.kit.agentkit import WORLD, start_agent_context, start_runner
from tests.kit.courses import assignment_toml, import_roster
from tests.kit.lab import PASSWORD, ProcessLab, make_lab

pytestmark = [pytest.mark.timeout(300), needs_sandbox]
GRADERS = Path(__file__).parent / "grading" / "graders"


def assignment(name: str, arena: str) -> str:
    return assignment_toml(
        name,
        time_limit="2.0",
        episodes="1",
        grader='"wobble.py"',
        goal_x=560,
        goal_radius=80,
        rule='100 * reached("goal") - metric("wobble")',
        sections=f"""
            [real]
            arena = "{arena}"
            robot = "k1"
            time_limit = 3.0
            after = "simulation-passed"
            """,
    )


@dataclass
class RealLab:
    lab: ProcessLab
    body: SimBody
    bridge_args: list[str]

    def kill_bridge(self) -> None:
        next(p for p in self.lab.procs.started if p.name == "bridge").kill9()

    def start_bridge(self) -> None:
        """The bridge started again (by its supervisor, after a crash)."""
        again = self.lab.procs.start("bridge-again", self.bridge_args)
        self.lab.wait_alive(AliveKind.WORLD, WORLD, again)


@pytest.fixture
def real(router: Router, procs: Procs, tmp_path: Path) -> Iterator[RealLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    import_roster(lab)
    lab.account(wiring.service_account("grader", "grader"))
    (tmp_path / "wobble.py").write_bytes((GRADERS / "wobble.py").read_bytes())
    for name, arena in (("real-goal", "arena"), ("nowhere", "nowhere")):
        (tmp_path / f"{name}.toml").write_text(assignment(name, arena))
        done = course("--db", str(lab.db_path), "assignment", "add", str(tmp_path / f"{name}.toml"))
        assert done.returncode == 0, done.stderr
        assert f"real-robot attempt on {arena}/k1 (simulation-passed)" in done.stdout
    with SimBody.from_map(REPO / "maps" / "empty.json", seed=5) as body:
        emulator = KheperaEmulator(body, EmulatorOptions(link_path=str(tmp_path / "khepera0")))
        with emulator:
            port = f"{tmp_path / 'khepera0'}=k1@500,500,0"
            args = ["bridge", "--world", WORLD, "--port", port, *lab.net_args()]
            bridge = procs.start("bridge", args)
            lab.wait_alive(AliveKind.WORLD, WORLD, bridge)
            start_runner(lab)
            start_agent_context(lab, slot=3.0)
            lab.start_grader()
            yield RealLab(lab, body, args)


def real_row(grader: GraderClient, sub: str) -> tuple[SubmissionInfo, EpisodeResult]:
    """The submission once its real row is there."""
    for _ in range(180):
        found = grader.submissions("real-goal", submission=sub)[0]
        rows = [e for e in found.episodes if e.real]
        if rows:
            return found, rows[0]
        time.sleep(1.0)
    raise AssertionError(f"no real row: {found}")


def test_a_real_attempt_joins_the_submission_after_its_simulation_passed(
    real: RealLab, tmp_path: Path
) -> None:
    lab = real.lab
    with lab.client("alice") as client:
        grader = GraderClient(client)
        # The arena the assignment names is not in the lab: refused, nothing written.
        with pytest.raises(LabError, match="real-robot attempt on the arena nowhere, which is"):
            grader.submit("nowhere", source("works"), "works.py")
        assert grader.submissions("nowhere") == []
        sub = grader.submit("real-goal", source("works"), "works.py").submission
        graded = grader.wait_graded("real-goal", sub, 120)
        assert graded.status == "graded", graded
        found, row = real_row(grader, sub)
        # The bridge dies during the next real attempt: the lab's fault, queued again free.
        again = grader.submit("real-goal", source("works"), "works.py").submission
        assert grader.wait_graded("real-goal", again, 120).status == "graded"
        wait_for(lambda: real.body.speed() != (0, 0), 60, "the real attempt to drive the robot")
        real.kill_bridge()
        with lab.client("ida") as teacher:  # the context's slot runs on without the robot
            arena = AgentClient(teacher, "arena").join()

            def slot_over() -> bool:
                return not any(e.position == 0 for q in arena.state().agents for e in q.entries)

            wait_for(slot_over, 30, "the real run's slot to end")
        real.start_bridge()
        _, retried = real_row(grader, again)
    assert retried.cause == "ok" and retried.lab_reruns >= 1, retried
    assert "after a lab fault, free" in retried.detail
    assert [e.real for e in found.episodes] == [False, True]  # simulated, then real
    assert row.cause == "ok", row
    assert row.detail.startswith("on arena/k1: ran its slot"), row.detail
    # Scored from the recording as in simulation: the goal reached, the grader's wobble.
    assert row.metrics["time_to_goal"] < 3.0 and row.metrics["distance_m"] > 0.05, row
    assert row.score == pytest.approx(100 - row.metrics["wobble"], abs=1e-3)
    assert "real-robot attempt: points" in found.message, found.message
    pw = tmp_path / "pw"
    pw.write_text(PASSWORD)
    board = wart(
        lab, "leaderboard", "real-goal", "--user", "ida", "--password-file", str(pw),
        *lab.net_args(),
    )  # fmt: skip
    assert board.returncode == 0, board.stderr
    assert f"real {row.score:g}" in board.stdout, board.stdout
