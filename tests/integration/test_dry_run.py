"""Dry runs: a controller's few simulated seconds in a private world, in the real sandbox.

The first tests play the runner (services/runner/dryrun.py's ``dry_run`` on a
snapshot of the foraging map); the last goes the whole way with real
processes: ``wart deploy --dry-run`` -> agent context -> runner -> report.
"""

from __future__ import annotations

import json
import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.client.agent_client import FINAL
from common.messages import WorldSnapshot
from common.recording import read_recording, summarize
from common.recording.report import describe
from common.sim2d import maps
from common.twin.twinfile import parse_twin
from common.world import packing
from services.runner.dryrun import dry_run, wall_limit
from tests.conftest import REPO, Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    agent_user,
    start_agent_lab,
    start_deploy,
)
from tests.kit.lab import ProcessLab, make_lab
from tests.unit.common.twin.test_twin_store import FITTED_AT, calibration

pytestmark = [pytest.mark.one_worker, needs_sandbox]
HEADER = "from common.controller import Controller, Khepera\n"
INTO_THE_WALL = HEADER + textwrap.dedent(
    """
    class Charge(Controller):
        def do_work(self, robot: Khepera) -> None:
            robot.set_speeds(127, 127)  # k3 faces the east wall, past a ball
    """
)


@pytest.fixture(scope="module")
def snap() -> WorldSnapshot:
    world = maps.load_map(REPO / "maps" / "foraging.json", name="w1", seed=3)
    return packing.snapshot(world)


def test_driving_into_a_wall_runs_with_a_warning(snap: WorldSnapshot) -> None:
    report = dry_run(snap, "k3", INTO_THE_WALL.encode())
    assert report.will_run
    assert report.verdict.startswith("will run, with a warning: 1 collision, the first with a wall")
    # Pushing a ball on the way is not even a warning (foraging does it); the wall is.
    assert [c.what for c in report.collisions] == ["object", "wall"]
    assert report.saturated == report.commands > 0  # every command at top speed
    assert report.sim_seconds == pytest.approx(5.0)


def test_an_exception_names_its_line(snap: WorldSnapshot) -> None:
    source = HEADER + textwrap.dedent(
        """
        class Divide(Controller):
            def do_work(self, robot: Khepera) -> None:
                robot.set_speeds(3, 3)
                if robot.time() > 0.5:
                    print("about to fail")
                    robot.set_speeds(1 // 0, 0)
        """
    )
    line = source.splitlines().index("            robot.set_speeds(1 // 0, 0)") + 1
    # As a runner whose registry did not answer would run it: the model line says so.
    why = "the registry did not give k1's twin"
    report = dry_run(snap, "k1", source.encode(), why_not_twin=why)
    assert report.model == f"the datasheet Khepera ({why})", report.model
    assert not report.will_run
    assert report.error_line == line
    assert report.verdict.startswith(f"will NOT run: line {line}: ZeroDivisionError")
    assert "about to fail" in report.output
    assert 0.4 < report.sim_seconds < 1.0  # it failed at its first step past 0.5 s


def test_a_well_behaved_example_will_run(snap: WorldSnapshot) -> None:
    source = (REPO / "examples" / "01_braitenberg.py").read_bytes()
    report = dry_run(snap, "k3", source, filename="01_braitenberg.py")
    assert report.will_run, report
    assert report.verdict.startswith("will run")
    assert report.sim_seconds == pytest.approx(5.0)
    assert not [c for c in report.collisions if c.what != "object"]


def test_example_01_runs_a_minute_in_the_default_arena_without_a_collision(
    snap: WorldSnapshot,
) -> None:
    """The first example a newcomer runs, in the arena `wart up` gives them, on any robot:
    a simulated minute touching no wall, rock or robot (pushing a ball is fine)."""
    source = (REPO / "examples" / "01_braitenberg.py").read_bytes()
    for agent in ("k0", "k1", "k2", "k3"):
        # The lab's wall-clock cap for a dry run (20 s) is not what this asks: a busy machine
        # may take longer over a simulated minute, and that says nothing about collisions.
        report = dry_run(
            snap, agent, source, filename="01_braitenberg.py", seconds=60.0, wall_s=600.0
        )
        assert report.verdict.startswith("will run"), (agent, report.verdict)
        assert report.sim_seconds == pytest.approx(60.0)


@pytest.mark.parametrize(
    ("name", "body"),
    [
        ("endless loop", "while True:\n            pass"),
        (
            "fork bomb",
            "import os\n        while True:\n            try:\n                os.fork()\n"
            "            except OSError:\n                pass",
        ),
    ],
)
def test_a_hostile_controller_ends_within_its_limit(
    snap: WorldSnapshot, name: str, body: str
) -> None:
    source = HEADER + (
        "\n\nclass Hostile(Controller):\n"
        "    def do_work(self, robot: Khepera) -> None:\n"
        f"        {body}\n"
    )
    # The shortest run: the test waits out the whole wall-clock limit, 5 s + 3x this.
    seconds = 0.2
    report = dry_run(snap, "k2", source.encode(), seconds=seconds)
    assert not report.will_run
    assert f"did not answer within {wall_limit(seconds):g} s" in report.verdict, report.verdict
    # It returned: the wall-clock limit ended it (the bound is loose: a loaded machine).
    assert report.wall_seconds < wall_limit(seconds) + 15


LOOK = HEADER + textwrap.dedent(
    """
    class Look(Controller):
        period = 0.1

        def do_work(self, robot: Khepera) -> None:
            print("ir", *robot.proximity().values)
            robot.stop()
    """
)


def test_a_twins_sensor_at_half_gain_reads_half_in_a_dry_run() -> None:
    """k1 faces a wall 20 mm off its front sensors; its twin's sensor 3 has gain 0.5."""
    room = {
        "format": "wart-map", "version": 1, "name": "real", "arena": {"width": 1000,
        "height": 1000}, "agents": [{"id": "k1", "type": "khepera", "x": 955, "y": 500}],
    }  # fmt: skip
    snap = packing.snapshot(maps.build_world(room, name="real", seed=2))
    doc = json.loads(calibration().to_json("carol", FITTED_AT))
    doc["parameters"]["ir3_gain"] = {"value": 0.5, "sigma": 0.01, "datasheet": 1.0, "unit": "",
                                     "runs": ["dance"], "refused": ""}  # fmt: skip
    twin = parse_twin(json.dumps(doc))

    def readings(with_twin: bool) -> np.ndarray:
        report = dry_run(snap, "k1", LOOK.encode(), seconds=1.5, twin=twin if with_twin else None)
        assert report.will_run, report
        rows = [line.split()[1:] for line in report.output if line.startswith("ir ")]
        assert len(rows) >= 8, report.output
        return np.array(rows[2:], dtype=float)  # after the first readings have come

    datasheet, copy = readings(False), readings(True)
    assert 150 < datasheet[:, 3].mean() < 350, datasheet  # the wall is where the test wants
    assert copy[:, 3].mean() / datasheet[:, 3].mean() == pytest.approx(0.5, abs=0.05)
    # Sensor 2 (gain 1.1 in this twin) and sensor 1 (not fitted: 1) read as the datasheet's.
    assert copy[:, 2].mean() / datasheet[:, 2].mean() == pytest.approx(1.1, abs=0.06)
    assert copy[:, 1].mean() / datasheet[:, 1].mean() == pytest.approx(1.0, abs=0.06)


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    start_agent_lab(lab)
    yield lab


def test_wart_deploy_dry_run_through_the_lab(lab: ProcessLab, tmp_path: Path) -> None:
    charge = tmp_path / "charge.py"
    charge.write_text(INTO_THE_WALL)
    proc = start_deploy(lab, charge, "k3", "bob", "--dry-run")
    assert proc.popen.wait(60) == 0, proc.output()  # a collision warns; it does not fail
    out = proc.output()
    assert "will run, with a warning: " in out and "collision at " in out
    assert "wheel commands at top speed" in out
    with agent_user(lab, "alice") as alice:
        source = (REPO / "examples" / "01_braitenberg.py").read_bytes()
        report = alice.dry_run("k2", source, filename="01_braitenberg.py")
        assert report.will_run, report
        assert all(not q.entries for q in alice.state().agents)  # nothing was queued


PUSH = HEADER + textwrap.dedent(
    """
    class Push(Controller):
        def do_work(self, robot: Khepera) -> None:
            robot.set_speeds(20, 20)  # k0 stands behind k2: it pushes k2 along
    """
)


def test_the_dry_run_and_the_recording_agree_on_a_robot_pushed(
    lab: ProcessLab, tmp_path: Path
) -> None:
    """A controller driven into the robot ahead: the dry run warns of that collision,
    and once run anyway, its recording's summary counts the same one, with a robot."""
    with agent_user(lab, "alice") as alice:
        report = alice.dry_run("k0", PUSH.encode(), filename="push.py", seconds=2.0)
        assert report.verdict.startswith(
            "will run, with a warning: 1 collision, the first with a robot k2"
        )
        queued = alice.queue("k0", "deploy", source=PUSH.encode(), filename="push.py")
        final = alice.wait_status(queued.request_id, FINAL, timeout=30)
        assert final is not None and final.status == "finished", final
        path = tmp_path / "push.mcap"
        wait_for(
            lambda: queued.request_id in {r.name for r in alice.recordings().recordings},
            20,
            "the push's recording",
        )
        alice.download(queued.request_id, path)
    summary = summarize(read_recording(path))
    assert summary.collided_with == {"robot": 1}, summary
    assert summary.collisions == 1
    assert any("collisions:  1: 1 with a robot" in line for line in describe(summary))
