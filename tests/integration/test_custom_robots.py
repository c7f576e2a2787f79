"""Nobody breaks anybody: a robot of a type built in the lab, placed in the shared arena,
leaves every other student's dry run working, in a real lab (router, registry, engine,
runner, agent context as processes).

The teacher saves a robot type to the world (the page's builder does the same request)
and adds a robot of it with "Add robot"'s edit; the runner, which has none of the lab's
robot files, simulates it from the file the world's snapshot carries. A type the runner
cannot simulate (a component only the engine has: a plugin installed on its host) fails
the dry runs in that arena with the robot and the reason, and nothing else; deleting the
robot ends that. "Add robot" asked for an occupied spot puts the robot beside it.
"""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from common import keys
from common.auth import Session, issue_session
from common.client.agent_client import FINAL
from common.client.grader_client import GraderClient
from common.lab_errors import RequestFailed
from common.messages import (
    AddItem,
    EditResult,
    Episode,
    ErrorReply,
    Message,
    RemoveItem,
    RobotTypeReply,
    RobotTypeRequest,
    WorldEdit,
    WorldSnapshot,
    decode,
)
from common.recording import read_recording
from common.sim2d import maps
from services.grader.assignment import parse_assignment
from services.runner.episode import run_episode
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import agent_user, start_agent_context, start_runner, together
from tests.kit.courses import assignment_toml, start_grading_lab
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.procs import REPO, wart

pytestmark = [pytest.mark.timeout(400), needs_sandbox]
PLUGIN = REPO / "examples" / "plugins" / "wart-race"

SCOUT = """\
format = "wart-robot"
version = 1
name = "epuck_ranger"

[components.body]
type = "body"
radius_mm = 35.0
mass_g = 150.0

[components.drive]
type = "differential_drive"
wheel_base_mm = 53.0
mm_per_pulse = 0.13
unit_time_s = 0.01
max_speed = 100

[components.eye]
type = "range_finder"
pose = [35.0, 0.0, 0.0]
beams = 3
fov_deg = 40.0
max_range_mm = 300.0
"""

# Only the engine's host has the lab_compass plugin: the runner cannot simulate this.
COMPASS_BOT = (
    SCOUT.replace('"epuck_ranger"', '"compass_bot"')
    + '\n[components.compass]\ntype = "lab_compass"\n'
)

BRAITENBERG = (REPO / "examples" / "01_braitenberg.py").read_bytes()
LOOK = textwrap.dedent(
    """\
    from common.controller import Controller


    class Look(Controller):
        period = 0.1

        def do_work(self, robot):
            print(f"eye {robot.eye().values}")
            robot.set_speeds(0, 0)
    """
).encode()


def plugin_site(tmp_path: Path) -> Path:
    """A directory on the engine's path declaring a compass component as an installed
    plugin's (entry points are found on the path, as pip would install them). Named
    lab_compass: no plugin another test installs in this environment gives it."""
    site = tmp_path / "engine-site"
    dist = site / "compass_only-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: compass-only\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[wart.components]\nlab_compass = compass_only:LabCompass\n"
    )
    (site / "compass_only.py").write_text(
        "from wart_race.sensors import RaceCompass\n\n\n"
        "class LabCompass(RaceCompass):\n    name = 'lab_compass'\n"
    )
    return site


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    env = {"PYTHONPATH": f"{plugin_site(tmp_path)}:{PLUGIN}:{REPO}"}
    together(lambda: lab.start_engine("foraging", env=env), lambda: start_runner(lab))
    start_agent_context(lab)
    yield lab


class Teacher:
    """The map editor's and the robot builder's requests, sealed as a teacher's."""

    def __init__(self, lab: ProcessLab) -> None:
        self.lab = lab
        self.realm = lab.realm
        self.session: Session = issue_session(lab.identity, lab.realm, "ida", ["edit_map"])

    def _ask(self, key: str, message: Message, expected: type) -> Message:
        with self.lab.zsession() as z:
            payload = self.session.seal(key, message)
            for reply in z.get(key, payload=payload, timeout=10.0):
                assert reply.ok is not None
                return decode(reply.ok.payload, (expected, ErrorReply))
        raise AssertionError(f"no reply on {key}")

    def save_type(self, text: str) -> Message:
        key = keys.world_robots(self.realm, "w1")
        return self._ask(key, RobotTypeRequest(action="save", text=text), RobotTypeReply)

    def add_robot(self, ident: str, kind: str, x: float, y: float) -> Message:
        entry = {"id": ident, "type": kind, "x": x, "y": y, "heading_deg": 0.0}
        op = AddItem(section="agents", entry=entry, nearest_free=True)
        return self._ask(keys.world_edit(self.realm, "w1"), WorldEdit(op=op), EditResult)

    def delete(self, ident: str) -> Message:
        key = keys.world_edit(self.realm, "w1")
        return self._ask(key, WorldEdit(op=RemoveItem(id=ident)), EditResult)

    def snapshot(self) -> WorldSnapshot:
        with self.lab.zsession() as z:
            for reply in z.get(keys.world_snapshot(self.realm, "w1"), timeout=10.0):
                assert reply.ok is not None
                snap = decode(reply.ok.payload, (WorldSnapshot, ErrorReply))
                assert isinstance(snap, WorldSnapshot), snap
                return snap
        raise AssertionError("no snapshot")


def test_a_custom_robot_leaves_everyone_s_dry_run_working(lab: ProcessLab) -> None:
    teacher = Teacher(lab)
    saved = teacher.save_type(SCOUT)
    assert isinstance(saved, RobotTypeReply), saved
    # "Add robot" twice: the arena's centre, by the rock (a 35 mm robot there would touch
    # it), then the same centre with e1 beside the rock: each at the nearest free spot.
    assert isinstance(teacher.add_robot("e1", "epuck_ranger", 800, 600), EditResult)
    assert isinstance(teacher.add_robot("e2", "epuck_ranger", 800, 600), EditResult)
    snap = teacher.snapshot()
    pose = {a.id: (a.x, a.y) for a in snap.agents}
    assert pose["e1"] != pytest.approx((800, 600))
    assert math.dist(pose["e1"], pose["e2"]) >= 70  # touching nothing
    assert all(math.dist(pose[e], (800, 600)) < 120 for e in ("e1", "e2"))  # near the centre
    assert set(snap.robot_files) == {"epuck_ranger"}  # the type travels with the world

    with agent_user(lab, "alice") as alice:
        report = alice.dry_run("k2", BRAITENBERG, filename="01_braitenberg.py", seconds=2.0)
        assert report.will_run, report  # the runner rebuilt e1 and e2 from the type's file
    with agent_user(lab, "bob") as bob:  # the custom robot itself, its range finder read
        wait_for(
            lambda: "e1" in {a.agent for a in bob.state().agents}, 30, "e1 in the context's list"
        )
        report = bob.dry_run("e1", LOOK, filename="look.py", seconds=1.0)
        assert report.will_run and report.output, report
        eye = report.output[0]
        assert eye.startswith("eye (") and min(int(v) for v in eye[5:-1].split(",")) < 300, eye

    # A run recorded beside the custom robots is read back and promoted as any other.
    with agent_user(lab, "alice") as alice:
        queued = alice.queue("k2", "deploy", source=BRAITENBERG, filename="01_braitenberg.py")
        final = alice.wait_status(queued.request_id, FINAL, timeout=40)
        assert final is not None and final.status == "finished", final
        summary = lab.state / "rooms" / "recordings" / "arena" / "alice"
        done = summary / f"{queued.request_id}.summary.json"
        wait_for(done.exists, 20, "the run's recording")
        rec = read_recording(alice.download(queued.request_id, lab.state / "run.mcap"))
        assert rec.snapshot is not None and set(rec.snapshot.robot_files) == {"epuck_ranger"}
        promoted = alice.promote(rec, "k1")
        again = alice.wait_status(promoted.request_id, FINAL, timeout=40)
        assert again is not None and again.status == "finished", again


def test_a_type_the_runner_cannot_simulate_fails_only_that_arena_s_dry_runs_in_words(
    lab: ProcessLab,
) -> None:
    teacher = Teacher(lab)
    saved = teacher.save_type(COMPASS_BOT)  # the engine has the compass: it accepts it
    assert isinstance(saved, RobotTypeReply), saved
    assert isinstance(teacher.add_robot("c1", "compass_bot", 600, 900), EditResult)
    with agent_user(lab, "alice") as alice:
        with pytest.raises(RequestFailed) as refused:
            alice.dry_run("k2", BRAITENBERG, filename="01_braitenberg.py", seconds=1.0)
        said = str(refused.value)
        assert (
            "robot type 'compass_bot' (c1) is not valid here: compass_bot.toml:25: "
            "components.compass.type: unknown component type 'lab_compass'"
        ) in said, said
        assert isinstance(teacher.delete("c1"), EditResult)
        report = alice.dry_run("k2", BRAITENBERG, filename="01_braitenberg.py", seconds=1.0)
        assert report.will_run, report  # the runner was never broken: only that world was
    # Deleting the last robots (and an object) is fine too, and nobody's process complains.
    for ident in ("ball0", "k3", "k2", "k1", "k0"):
        assert isinstance(teacher.delete(ident), EditResult), ident
    assert teacher.snapshot().agents == []
    for proc in lab.procs.started:
        assert "Traceback" not in proc.output(), (proc.name, proc.output()[-2000:])


# Graded on the saved arena, from where the lab's robot stands (300, 500).
ASSIGNMENT = assignment_toml(
    "look-around",
    map='"class"',
    robot='"e1"',
    time_limit="2",
    episodes="1",
    goal_x=800,
    goal_radius=80,
    rule='100 * reached("goal")',
).encode()


def test_a_graded_episode_runs_on_a_map_saved_with_a_custom_robot(tmp_path: Path) -> None:
    """The teacher saves the arena with the robot built in the lab as a map and sets an
    assignment on it: the grader checks it and the runner grades on it, neither of them
    having the lab's robot files (the saved map carries the type's)."""
    saved_class_map(tmp_path)
    assignment, map_text = parse_assignment(ASSIGNMENT, "look.toml", tmp_path)
    assert assignment.robot == "e1" and '"epuck_ranger"' in map_text
    start = assignment.starts[0]
    episode = Episode(
        submission="s1",
        episode=0,
        user="alice",
        map=map_text,
        agent="e1",
        seed=1,
        x=start.x,
        y=start.y,
        heading=math.radians(start.heading_deg),
        seconds=1.0,
        source=LOOK,
        filename="look.py",
    )
    report = run_episode(episode)
    assert report.cause in ("ok", "finished"), report
    assert report.output and report.output[0].startswith("eye ("), report


def saved_class_map(directory: Path) -> Path:
    """The empty arena with a robot of the lab's own type beside its Khepera, saved as a
    map (as the page's Save map does): it carries the type's robot file."""
    room = json.loads((REPO / "maps" / "empty.json").read_text())
    room["robot_types"] = {"epuck_ranger": SCOUT}
    room["agents"].append({"id": "e1", "type": "epuck_ranger", "x": 300, "y": 500})
    return maps.save_map(maps.build_world(room, name="w1"), directory, "class")


@pytest.fixture
def grading_lab(router: Router, procs: Procs, tmp_path: Path) -> ProcessLab:
    """Registry (alice and ida in COURSE), runner and grader; no engine."""
    return start_grading_lab(router, procs, tmp_path)


def test_the_grader_grades_on_a_map_saved_with_a_custom_robot(
    grading_lab: ProcessLab, tmp_path: Path
) -> None:
    """The whole graded path with processes: `wart course assignment add` on the saved map,
    a student's submission, the grader's episodes on the runner, each ran its time."""
    saved_class_map(tmp_path)
    path = tmp_path / "look.toml"
    path.write_text(assignment_toml("look-around", map='"class.json"', robot='"e1"', episodes="1"))
    db = str(grading_lab.db_path)
    done = wart("course", "--db", db, "assignment", "add", str(path))
    assert done.returncode == 0, done.stderr
    with grading_lab.client("alice") as client:
        grader = GraderClient(client)
        accepted = grader.submit("look-around", LOOK, "look.py")
        graded = grader.wait_graded("look-around", accepted.submission, 180)
    assert graded.status == "graded", graded
    assert [e.cause for e in graded.episodes] == ["ok"], graded.episodes
