"""A class in the page (issue 36): the student's Course folder and the teacher's Class folder, live.

A real lab (router, registry, engine, runner, the agent context ``arena`` owned
by ida, long slots) and the grader as processes; the course (alice, bob,
carol; ida teaches) imported and an assignment added in the registry's
database as the teacher's tools do. One lab for the module.

- alice hands in the file open in her editor; her scores and the leaderboard
  show the graded score without a click, and so does ida's Class table (three
  students); alice has no Class folder, and the grader refuses her the class.
- alice's controller runs on k1; from ida's Class table: Watch (the view
  follows k1), Take over, drive by keyboard (arrow keys and WASD in the
  driving box or the world view; releasing the keys or losing focus stops
  it: the engine's poses say so), Hand back; alice's page says each step and
  the slot's recording keeps them, with ida's commands.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common.client.agent_client import FINAL
from common.client.grader_client import GraderClient
from common.lab_errors import LabError
from common.recording import read_recording
from tests.browser.conftest import CANVAS_AT_JS, wait_until
from tests.browser.test_real_agents import choose, enter_arena
from tests.browser.test_real_lab import session_of
from tests.conftest import needs_sandbox
from tests.kit.agentkit import Motion, agent_user
from tests.kit.classroom import course_lab
from tests.kit.courses import COURSE
from tests.kit.reallab import CTX, RealLab
from viewers.web.drive_keys import BOX_LABEL
from viewers.web.inputs import set_value

pytestmark = [
    pytest.mark.integration,
    pytest.mark.timeout(300),
    needs_sandbox,
    pytest.mark.real_lab,
]
REPO = Path(__file__).resolve().parents[2]
WORKS = (REPO / "tests" / "integration" / "grading" / "works.py").read_text()
RAISES = (REPO / "tests" / "integration" / "grading" / "raises.py").read_text()
FORWARD = (REPO / "tests" / "integration" / "controllers" / "forward.py").read_bytes()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with course_lab(Path(tmp_path_factory.mktemp("courselab"))) as env:
        yield env


def cell(page, name: str):  # type: ignore[no-untyped-def]
    return page.p.get_by_role("cell", name=name, exact=True).first


def test_scores_reach_the_students_page_and_the_class_table_without_a_click(
    open_page, lab: RealLab
) -> None:
    ida, alice = open_page("ida"), open_page("alice")
    ida_panel = enter_arena(ida, lab, "ida")
    klass = ida_panel.klass
    assert klass is not None
    wait_until(lambda: klass.folder.visible, 15, what="ida's Class folder")
    for name in ("Alice A (alice)", "bob", "carol"):  # the three students, not the teacher
        cell(ida, name).wait_for(timeout=10_000)
    assert ida.p.get_by_role("cell", name="no submission").count() == 3

    panel = enter_arena(alice, lab, "alice")
    course, workbench = panel.course, panel.workbench
    assert course is not None and workbench is not None
    assert panel.klass is not None and not panel.klass.folder.visible
    assert alice.p.get_by_role("application", name=BOX_LABEL).count() == 0  # no Class folder
    with lab.lab.client("alice") as client:  # and the grader refuses her if she asks
        assert GraderClient(client).class_tables() == []
        with pytest.raises(LabError, match=f"only the teachers of {COURSE} see its class"):
            GraderClient(client).class_tables(COURSE)

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
    # No click from here on: the grader's word that it changed brings each page the score.
    cell(alice, "graded").wait_for(timeout=120_000)
    cell(alice, "99.62").wait_for(timeout=10_000)
    cell(alice, "Alice A").wait_for(timeout=10_000)  # the leaderboard
    ida_row = ida.p.get_by_role("row").filter(has=cell(ida, "Alice A (alice)"))
    ida_row.get_by_role("cell", name="99.62", exact=True).wait_for(timeout=10_000)
    assert ida_row.get_by_role("cell", name="graded", exact=True).count() == 1
    cell(ida, "Alice A (alice)").scroll_into_view_if_needed()
    ida.screenshot("class-table")
    # Her episodes one by one: the score term by term, the rule as written (not escaped).
    alice.wait_text("episode by episode", timeout=10_000)
    alice.p.get_by_text('100 * reached("goal")', exact=True).first.wait_for(timeout=10_000)

    # A submission that raises: she reads the error and its line, as the teacher does.
    set_value(workbench.name, "raises.py")
    set_value(workbench.code, RAISES)
    alice.click("Submit the editor's code")
    alice.wait_text("ZeroDivisionError: division by zero on purpose", timeout=120_000)
    alice.wait_text("your controller: line 13:", timeout=10_000)
    alice.screenshot("course-episode-error")


def test_the_teacher_watches_takes_over_drives_by_keyboard_and_hands_back(
    open_page, lab: RealLab
) -> None:
    ida, alice = open_page("ida"), open_page("alice")
    ida_panel = enter_arena(ida, lab, "ida")
    enter_arena(alice, lab, "alice")
    klass, robots = ida_panel.klass, ida_panel.robots
    assert klass is not None and robots is not None
    wait_until(lambda: klass.folder.visible, 15, what="ida's Class folder")

    motion = Motion(lab.session, lab.router.realm)
    with agent_user(lab.lab, "alice") as al:
        rid = al.queue("k1", "deploy", source=FORWARD, filename="forward.py").request_id
        assert al.wait_status(rid, {"running"}, timeout=60), "alice's controller never ran"
        wait_until(lambda: motion.moving(["k1"], 0.0), 30, what="alice's controller driving")
        ida.wait_text("k1, ", timeout=15_000)  # her live run in the class table

        choose(ida, "Student", "alice")
        wait_until(lambda: klass.student.value == "alice", 10, what="alice chosen")
        ida.click("Watch their robot")
        ida.wait_text("Watching alice's robot k1: the view follows it.")
        view = robots.view
        assert view is not None and view.follow and view.selected_name == "k1"

        taken = time.monotonic()
        ida.click("Take over their robot")
        ida.wait_text("k1 taken over from alice: their controller is paused")
        alice.wait_text("your robot is driven by ida since", timeout=15_000)
        wait_until(lambda: motion.at_rest_since(["k1"], taken), 20, what="k1 paused at rest")

        box = ida.p.get_by_role("application", name=BOX_LABEL)
        box.click()
        pressed = time.monotonic()
        ida.p.keyboard.down("ArrowDown")
        wait_until(lambda: motion.moving(["k1"], pressed), 20, what="k1 driven by a key")
        released = time.monotonic()
        ida.p.keyboard.up("ArrowDown")
        wait_until(lambda: motion.at_rest_since(["k1"], released), 20, what="stopped on release")

        # WASD too, forward: backing up three times drove k1 into the wall on a busy
        # machine (each key held until the robot was seen moving), and then nothing moved.
        pressed = time.monotonic()
        ida.p.keyboard.down("KeyW")  # then the box loses focus with the key held
        wait_until(lambda: motion.moving(["k1"], pressed), 20, what="k1 driven by W")
        blurred = time.monotonic()
        ida.p.get_by_text("Drive with the arrow keys or WASD", exact=False).first.click()
        wait_until(lambda: motion.at_rest_since(["k1"], blurred), 20, what="stopped on blur")
        ida.p.keyboard.up("KeyW")

        # A click on the world view focuses it, and then keys drive. Clicked where the DOM
        # says the canvas itself is, and waited until it has the focus (a fresh-clone run's
        # keys drove nothing after a click at the canvas's centre: no focus, no keys).
        canvas = ida.p.locator("canvas[data-engine]").first
        box = canvas.bounding_box()
        assert box is not None
        spots = [
            (box["x"] + box["width"] * fx, box["y"] + box["height"] * fy)
            for fx, fy in ((0.5, 0.75), (0.75, 0.5), (0.25, 0.75), (0.5, 0.5))
        ]
        spot = next((xy for xy in spots if ida.p.evaluate(CANVAS_AT_JS, list(xy))), None)
        assert spot is not None, f"no point of the world view is uncovered: {spots}"
        ida.p.mouse.click(*spot)
        wait_until(
            lambda: ida.p.evaluate("() => document.activeElement?.tagName") == "CANVAS",
            10,
            what=lambda: (
                "the world view focused; focus is on "
                + str(ida.p.evaluate("() => document.activeElement?.outerHTML.slice(0, 120)"))
            ),
        )
        # Keys held for driving never fly the view's camera (viser's own WASD and arrows):
        # its orientation, as the browser reports it to the server, stays as it was.
        camera = session_of(lab.viewer, "ida").client.camera
        facing = np.array(camera.wxyz)
        pressed = time.monotonic()
        ida.p.keyboard.down("ArrowDown")
        wait_until(lambda: motion.moving(["k1"], pressed), 20, what="k1 driven from the view")
        ida.p.keyboard.down("KeyA")
        ida.p.wait_for_timeout(1000)  # a second of viser's 50 deg/s would tip it 50 degrees
        ida.p.keyboard.up("KeyA")
        ida.p.keyboard.up("ArrowDown")
        turned = 2 * np.degrees(np.arccos(min(1.0, abs(float(np.dot(facing, camera.wxyz))))))
        assert turned < 1.0, f"the camera turned {turned:.1f} degrees while ida drove"
        ida.screenshot("class-driving")

        ida.click("Hand their robot back")
        ida.wait_text("k1 handed back to alice's controller")
        alice.wait_text("ida handed your robot back: your controller drives again", 15_000)
        resumed = time.monotonic()
        wait_until(lambda: motion.moving(["k1"], resumed), 20, what="alice's controller again")
        assert al.wait_status(rid, FINAL, timeout=0.2) is None  # the same slot goes on
        al.cancel(rid)
        assert al.wait_status(rid, FINAL, timeout=20) is not None
    motion.close()

    # The slot's recording keeps each step, and ida's keyboard commands as hers.
    path = lab.lab.state / "rooms" / "recordings" / CTX / "alice" / f"{rid}.mcap"
    wait_until(path.with_name(f"{rid}.summary.json").exists, 20, what="the run's recording")
    rec = read_recording(path)
    kinds = [e.record.kind for e in rec.events if e.record.request_id == rid]
    assert kinds.index("started") < kinds.index("taken") < kinds.index("handed_back")
    assert "ida" in {c.record.sender for c in rec.commands}
