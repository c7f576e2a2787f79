"""Runtime module loading, proved by a plugin outside the core (issue 34).

examples/plugins/wart-race is pip-installed into the test's environment (no
dependencies: the lab is already there) and uninstalled afterwards. Then, in a
real lab with no change to the project: its racer robot stands in an arena,
a deployed controller reads its new compass sensor (and the range finder and
bumper it carries) by the names of its robot file, and its race context type,
started as ``wart context race``, counts the racer's lap across the start line.

Also from the command line, as a user sees them: bad robot files refused with
the file, line and field; and plugins that fail to import or declare a bad
schema reported by ``wart doctor`` with the reason while the lab runs on.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import pytest

from common import keys
from common.auth import issue_session
from common.messages import (
    AddItem,
    EditResult,
    ErrorReply,
    RobotTypeReply,
    RobotTypeRequest,
    WorldEdit,
    decode,
)
from services.lab import wiring
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import start_agent_context, start_deploy, together
from tests.kit.lab import ProcessLab, make_lab
from tests.kit.procs import REPO
from tests.kit.robots import SCOUT, wheeled_robot

pytestmark = pytest.mark.timeout(400)
PLUGIN = REPO / "examples" / "plugins" / "wart-race"

RACE_MAP = {
    "format": "wart-map",
    "version": 1,
    "name": "race",
    "arena": {"width": 1000, "height": 600},
    "floor": {"lines": [{"points": [[400, 50], [400, 550]], "width": 10}]},
    "agents": [
        {"id": "r0", "type": "racer", "x": 150, "y": 300, "heading_deg": 0},
        {"id": "k0", "type": "khepera", "x": 150, "y": 100, "heading_deg": 0},
    ],
}

RACER = textwrap.dedent(
    """\
    from common.controller import Controller


    class Racer(Controller):
        period = 0.05

        def initialize(self, robot):
            self.n = 0

        def do_work(self, robot):
            if self.n % 5 == 0:
                print(f"compass {robot.compass().values[0]} eye {robot.eye().values[2]} "
                      f"bump {sum(robot.bump().values)} sensors {','.join(robot.sensors())}")
            self.n += 1
            robot.set_speeds(60, 60)
    """
)


def _installed() -> bool:
    try:
        metadata.distribution("wart-race")
    except metadata.PackageNotFoundError:
        return False
    return True


@pytest.fixture(scope="module")
def race_plugin() -> Iterator[None]:
    """wart-race installed with pip into this environment, removed after (if it was not there)."""
    was_there = _installed()
    if not was_there:
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "-q", "--no-deps", str(PLUGIN)],
            check=True,
            capture_output=True,
            timeout=300,
        )
    try:
        yield
    finally:
        if not was_there:
            subprocess.run(
                [sys.executable, "-m", "pip", "uninstall", "-y", "-q", "wart-race"],
                check=False,
                capture_output=True,
                timeout=120,
            )


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path, race_plugin: None) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    w = lab.wiring()
    w.maps_dir.mkdir(parents=True, exist_ok=True)
    map_path = w.maps_dir / "race.json"
    map_path.write_text(json.dumps(RACE_MAP))
    together(
        lambda: lab.start(wiring.engine_spec(w, "w1", map_path, seed=3), name="engine"),
        lambda: lab.start_runner(),
    )
    start_agent_context(lab, slot=3.0)
    yield lab


@needs_sandbox
def test_the_plugin_s_robot_sensor_and_race_run_in_a_real_lab(
    lab: ProcessLab, procs: Procs, tmp_path: Path
) -> None:
    listed = procs.start("robots-list", ["robots", "list"])
    assert listed.popen.wait(60) == 0, listed.output()
    out = listed.output()
    assert re.search(r"racer +wart-race 0\.1\.0: .*compass:race_compass", out), out
    assert re.search(r"race +wart-race 0\.1\.0", out), out

    result = tmp_path / "race.json"
    race = procs.start(
        "race",
        ["context", "race", "--world", "w1", "--start", "400,550,400,50", "--laps", "1",
         "--result", str(result), "--seconds", "60", "--exit-when-done", *lab.net_args()],
    )  # fmt: skip
    wait_for(lambda: "race on w1: 2 robots" in race.output(), 30, "the race to start")

    source = tmp_path / "racer.py"
    source.write_text(RACER)
    deploy = start_deploy(lab, source, "r0", "bob")
    assert deploy.popen.wait(60) == 0, deploy.output()
    out = deploy.output()
    pattern = r"\[r0\] compass (\d+) eye (\d+) bump (\d+) sensors (\S+)"
    readings = [(int(c), int(e), int(b), s) for c, e, b, s in re.findall(pattern, out)]
    assert len(readings) >= 5, out
    compass, eye, _, sensors = readings[0]
    assert sensors == "compass,eye,bump"  # the names of the robot file
    assert compass in (0, 1, 3599)  # facing east, tenths of a degree
    assert eye == 400  # the far wall is out of the range finder's 400 mm
    assert min(e for _, e, _, _ in readings) < 400, "the racer drove up to the wall"

    assert race.popen.wait(60) == 0, race.output()
    standings = json.loads(result.read_text())
    assert standings["winner"] == "r0"
    assert standings["standings"][0] == {"agent": "r0", "laps": 1, "finished_at": pytest.approx(
        standings["standings"][0]["finished_at"])}  # fmt: skip
    assert {"agent": "k0", "laps": 0, "finished_at": None} in standings["standings"]


GOOD = wheeled_robot("scout")


@pytest.mark.parametrize(
    ("text", "said"),
    [
        (
            GOOD + '\n[components.gun]\ntype = "laser_cannon"\n',
            # (and any plugin's components: the lab's, whatever is installed)
            "scout.toml:18: components.gun.type: unknown component type 'laser_cannon' "
            "(this lab has: ambient_light, body, bumper, differential_drive, floor_sensor, ",
        ),
        (
            GOOD.replace("mass_g = 80.0", "mass_g = [80]"),
            "scout.toml:8: components.body.mass_g: must be a number, got [80]",
        ),
        (
            GOOD.replace("max_speed = 100\n", ""),
            "scout.toml:10: components.drive.max_speed: is required "
            "(commands are clamped to ±max_speed units)",
        ),
        (
            GOOD + "#" * 70_000,
            f"scout.toml: file: is {len(GOOD) + 70_000} bytes; robot files are limited to 65536",
        ),
    ],
    ids=["unknown component", "wrong type", "missing field", "huge file"],
)
def test_bad_robot_files_are_refused_from_the_cli_with_the_line_and_field(
    procs: Procs, tmp_path: Path, text: str, said: str
) -> None:
    path = tmp_path / "scout.toml"
    path.write_text(text)
    proc = procs.start("robots-check", ["robots", "check", str(path)])
    assert proc.popen.wait(60) == 1
    lines = proc.output().splitlines()
    assert any(line.startswith(said) for line in lines), proc.output()
    assert lines[-1].startswith("scout.toml: refused (1 problem(s))")


def test_a_broken_plugin_is_reported_by_doctor_and_the_lab_runs_without_it(
    procs: Procs, tmp_path: Path
) -> None:
    """Two installed plugins (entry points found on the path): one fails to import, one's
    schema is bad. Both are named with the reason; every built-in type is still there."""
    site = tmp_path / "site"
    dist = site / "broken_plugins-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugins\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[wart.components]\nmissing = no_such_module_anywhere:Thing\n"
        "sloppy = sloppy_plugin:Sloppy\n"
    )
    (site / "sloppy_plugin.py").write_text(
        textwrap.dedent(
            """\
            from common.robots.schema import ComponentType, Param

            class Sloppy(ComponentType):
                name = "sloppy"
                doc = "a sensor whose schema is wrong"
                params = (Param("gain", "numbr", "how much"),)
            """
        )
    )
    env = {"PYTHONPATH": f"{site}:{REPO}"}
    doctor = procs.start("doctor", ["doctor", "--plugins"], env=env)
    assert doctor.popen.wait(60) == 1
    out = doctor.output()
    assert "✓ broken-plugins 0.1" not in out
    assert (
        "plugin refused, the lab runs without it: wart.components missing (from "
        "broken-plugins 0.1): failed to import: ModuleNotFoundError: No module named "
        "'no_such_module_anywhere'"
    ) in out, out
    assert (
        "wart.components sloppy (from broken-plugins 0.1): bad schema: sloppy.gain: unknown "
        "kind 'numbr'"
    ) in out, out
    listed = procs.start("robots-list", ["robots", "list"], env=env)
    assert listed.popen.wait(60) == 0
    assert re.search(r"khepera +built-in", listed.output())


SCOUT_READER = textwrap.dedent(
    """\
    from common.controller import Controller


    class Look(Controller):
        period = 0.05

        def do_work(self, robot):
            print(f"eye {robot.eye().values}")
            robot.set_speeds(0, 0)
    """
)


@needs_sandbox
def test_a_robot_type_saved_to_the_lab_drives_in_its_arena(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    """The builder's path without the page: save a robot file to the world (edit_map),
    add a robot of it with the map editor's edit, run a controller that reads its range
    finder. A bad file and a student are refused, in words."""
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    together(lambda: lab.start_engine("foraging"), lambda: lab.start_runner())
    start_agent_context(lab, slot=2.0)
    realm = lab.realm
    editor = issue_session(lab.identity, realm, "ida", ["edit_map", "join"])
    student = issue_session(lab.identity, realm, "bob", ["control", "join"])
    key = keys.world_robots(realm, "w1")
    with lab.zsession() as z:

        def ask(payload: bytes) -> object:
            for reply in z.get(key, payload=payload, timeout=10.0):
                assert reply.ok is not None
                return decode(reply.ok.payload, (RobotTypeReply, ErrorReply))
            raise AssertionError("no reply")

        listed = ask(student.seal(key, RobotTypeRequest(action="list")))
        assert isinstance(listed, RobotTypeReply)
        assert {"khepera", "epuck"} <= {t.name for t in listed.types}
        assert "range_finder" in listed.component_types
        got = ask(student.seal(key, RobotTypeRequest(action="get", name="epuck")))
        assert isinstance(got, RobotTypeReply) and 'name = "epuck"' in got.text

        save = RobotTypeRequest(action="save", text=SCOUT)
        refused = ask(student.seal(key, save))
        assert isinstance(refused, ErrorReply) and refused.code == "forbidden"
        bad = ask(
            editor.seal(
                key, RobotTypeRequest(action="save", text=SCOUT.replace("beams = 3", "beams = 99"))
            )
        )
        assert isinstance(bad, ErrorReply) and bad.code == "bad_request"
        assert bad.message == "robot file:20: components.eye.beams: must be at most 64, got 99"
        khepera = ask(
            editor.seal(
                key, RobotTypeRequest(action="save", text=SCOUT.replace('"scout"', '"khepera"'))
            )
        )
        assert isinstance(khepera, ErrorReply) and "is the lab's (built-in)" in khepera.message
        saved = ask(editor.seal(key, save))
        assert isinstance(saved, RobotTypeReply), saved
        assert saved.detail.startswith(
            "saved robot type scout: body:body, drive:differential_drive"
        )
        assert (lab.wiring().robots_dir / "scout.toml").read_text() == SCOUT

        edit_key = keys.world_edit(realm, "w1")
        add = WorldEdit(
            op=AddItem(
                section="agents",
                entry={"id": "s1", "type": "scout", "x": 1000, "y": 150, "heading_deg": 90},
            )
        )
        for reply in z.get(edit_key, payload=editor.seal(edit_key, add), timeout=10.0):
            assert reply.ok is not None
            assert isinstance(decode(reply.ok.payload, (EditResult, ErrorReply)), EditResult)

    source = tmp_path / "look.py"
    source.write_text(SCOUT_READER)
    deploy = wait_for(lambda: _deployed(lab, source), 30, "s1 in the agent context's queue")
    out = deploy.output()
    eyes = re.findall(r"\[s1\] eye \((\d+), (\d+), (\d+)\)", out)
    assert eyes, out
    assert all(0 <= int(v) <= 300 for v in eyes[0])


def _deployed(lab: ProcessLab, source: Path) -> object:
    proc = start_deploy(lab, source, "s1", "bob")
    proc.popen.wait(60)
    return proc if proc.popen.returncode == 0 else None
