"""A class in a room, in Chromium against a real lab: a teacher and three students at once.

The students write, Check, dry-run and run in their own pages while the teacher
builds and places a robot of a new type; one student reloads mid-run and keeps the
run; the teacher takes over a student's robot by keyboard (the view's camera
unchanged) and hands it back; a graded submission fails and its student reads the
error and replays the episode. Every assertion is what a person sees in the DOM or
what the lab's services say, never pixels.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tests.browser.conftest import ViserPage, wait_until
from tests.browser.test_real_agents import choose, enter_arena
from tests.browser.test_real_lab import session_of
from tests.browser.test_reload_keeps_the_run import TICKING
from tests.browser.test_workbench import INTO_THE_WALL, write_code
from tests.conftest import needs_sandbox
from tests.kit.classroom import ASSIGNMENT, REPO, course_lab
from tests.kit.reallab import RealLab
from viewers.web.chat_panel import ChatPanel
from viewers.web.drive_keys import BOX_LABEL
from viewers.web.inputs import set_value

pytestmark = [
    pytest.mark.integration,
    pytest.mark.timeout(400),
    needs_sandbox,
    pytest.mark.real_lab,
]

GENTLE = TICKING.replace("Ticking", "Gentle").replace("set_speeds(2, 2)", "set_speeds(1, -1)")
RAISES = (REPO / "tests" / "integration" / "grading" / "raises.py").read_text()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with course_lab(Path(tmp_path_factory.mktemp("classdrill")), slot=600.0) as env:
        yield env


def ticks(page: ViserPage) -> list[int]:
    text = " ".join(page.p.locator(".wart-run-output pre").all_inner_texts())
    return [int(n) for n in re.findall(r"tick (\d+)", text)]


def bench_of(panel: ChatPanel):  # type: ignore[no-untyped-def]
    assert panel.workbench is not None
    return panel.workbench


def test_a_class_drill(open_page, lab: RealLab) -> None:
    ida = open_page("ida")
    alice, bob, carol = open_page("alice"), open_page("bob"), open_page("carol")
    panels = {who: enter_arena(page, lab, who) for who, page in
              (("ida", ida), ("alice", alice), ("bob", bob), ("carol", carol))}  # fmt: skip
    klass = panels["ida"].klass
    assert klass is not None
    wait_until(lambda: klass.folder.visible, 15, what="ida's Class folder")

    # Each student writes their controller and checks it.
    plans = ((alice, "alice", TICKING, "k0"), (bob, "bob", INTO_THE_WALL, "k3"),
             (carol, "carol", GENTLE, "k2"))  # fmt: skip
    for page, who, code, robot in plans:
        bench = bench_of(panels[who])
        write_code(page, code, lambda b=bench, c=code: b.code.value == c)
        choose(page, "Run on", robot)
        wait_until(lambda b=bench, r=robot: b.target.value == r, 10, what=f"{who} on {robot}")
    for page, _, _, _ in plans:
        page.click("Check")
    for page, _, _, _ in plans:
        page.wait_text("Check: no problems found", timeout=15_000)

    # The teacher builds a robot type of the lab's own (an e-puck with a range finder)...
    builder, editor = panels["ida"].builder, panels["ida"].editor
    assert builder is not None and editor is not None
    ida.p.get_by_text("Robot builder").first.click()
    ida.click("List types")
    ida.wait_text("This world has")
    choose(ida, "Start from", "epuck")
    ida.click("Open type")
    wait_until(lambda: 'name = "epuck"' in builder.text.value, 15, what="epuck's file")
    choose(ida, "Component", "range_finder")
    ida.click("Add component")
    wait_until(lambda: "[components.range]" in builder.text.value, 15, what="a range finder")
    set_value(builder.text, builder.text.value.replace('name = "epuck"', 'name = "scout"'))
    ida.click("Check robot file")
    ida.wait_text("Check: scout is a valid robot type", timeout=15_000)
    ida.click("Save type to the lab")
    ida.wait_text("Saved robot type scout", timeout=15_000)
    view = session_of(lab.viewer, "ida").view
    before = set(view.robot_names)

    # ...and places it while alice runs and bob and carol dry-run, all at once.
    ida.p.get_by_text("Map editor").first.click()
    alice.click("Run in simulation")
    bob.click("Dry run")
    carol.click("Dry run")
    ida.click("Add robot")
    alice.wait_text("Your controller runs on k0", timeout=60_000)
    bob.wait_text("on k3: will run, with a warning: 1 collision", timeout=60_000)
    carol.wait_text("Dry run of my_controller.py on k2 done: it will run,", timeout=60_000)
    wait_until(lambda: set(view.robot_names) - before, 30, what="the scout in the arena")
    (scout,) = set(view.robot_names) - before
    assert view.feed is not None and view.feed.snapshot().robot_types[scout][0] == "scout"
    wait_until(lambda: ticks(alice), 30, what="alice's first print under her editor")
    # Beside the custom robot, everyone's dry runs still work.
    choose(carol, "Run on", "k1")
    carol.click("Dry run")
    carol.wait_text("Dry run of my_controller.py on k1 done: it will run,", timeout=60_000)

    # Alice reloads mid-run: the run goes on, her page comes back as it was.
    before = max(ticks(alice))
    alice.p.reload()
    alice.wait_ready()
    alice.wait_text("Your controller runs on k0", timeout=30_000)
    back = next(iter(session_of(lab.viewer, "alice").labs.values())).panels["arena"]
    assert bench_of(back).code.value == TICKING
    wait_until(lambda: ticks(alice) and max(ticks(alice)) > before, 30, what="prints go on")

    # The teacher takes over alice's robot by keyboard, the view's camera unchanged.
    ida.wait_text("k0, ", timeout=30_000)  # her live run in the class table
    choose(ida, "Student", "alice")
    wait_until(lambda: klass.student.value == "alice", 10, what="alice chosen")
    ida.click("Take over their robot")
    ida.wait_text("k0 taken over from alice: their controller is paused", timeout=15_000)
    alice.wait_text("your robot is driven by ida since", timeout=15_000)
    camera = session_of(lab.viewer, "ida").client.camera
    facing = np.array(camera.wxyz)
    ida.p.get_by_role("application", name=BOX_LABEL).click()
    ida.p.keyboard.down("ArrowUp")
    ida.p.keyboard.down("KeyD")
    ida.p.wait_for_timeout(800)  # held as a person holds them; viser's keys would turn it
    ida.p.keyboard.up("KeyD")
    ida.p.keyboard.up("ArrowUp")
    turned = 2 * np.degrees(np.arccos(min(1.0, abs(float(np.dot(facing, camera.wxyz))))))
    assert turned < 1.0, f"the teacher's camera turned {turned:.1f} degrees while driving"
    ida.click("Hand their robot back")
    ida.wait_text("k0 handed back to alice's controller", timeout=15_000)
    alice.wait_text("ida handed your robot back: your controller drives again", timeout=15_000)

    # Carol hands in a controller that raises: she reads the error and its line.
    set_value(bench_of(panels["carol"]).code, RAISES)
    carol.p.get_by_text("Course", exact=True).first.click()
    carol.click("Refresh assignments")
    carol.wait_text("1 assignment(s) in your courses.")
    choose(carol, "Assignment", ASSIGNMENT)
    carol.click("Submit the editor's code")
    carol.wait_text("ZeroDivisionError: division by zero on purpose", timeout=120_000)
    carol.wait_text("your controller: line 13:", timeout=10_000)
    # ...and replays that episode in her world view, then goes back to the live arena.
    course = panels["carol"].course
    assert course is not None
    carol.click("Replay the episode")
    carol.wait_text("Replaying episode 0 of ", timeout=30_000)
    replay = course.spot.replay
    assert replay is not None and replay.player.timeline.duration > 0
    assert carol.p.get_by_text("Back to live").count() == 1
    carol.screenshot("class-drill-replay")
    carol.click("Back to live")
    wait_until(lambda: course.spot.replay is None, what="carol back to the live arena")

    # No run was lost: alice's is still hers, and Stop ends it.
    assert back.robots is not None and back.robots.driven("k0")
    alice.click("Stop")
    alice.wait_text("Your controller on k0 cancelled", timeout=15_000)
    for page in (ida, alice, bob, carol):
        page.screenshot("class-drill-end")
