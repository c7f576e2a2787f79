"""The arena's editor in Chromium against a real lab: write, Check, fix, run, see it move, stop.

Router, registry, engine (MAC leases), runner (bubblewrap sandboxes) and the
agent context ``arena``, as in test_real_agents; slots long enough that only
Stop ends the run.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tests.browser.conftest import ViserPage, wait_until
from tests.browser.test_real_agents import choose, enter_arena, pick_robot, upload
from tests.browser.test_real_lab import session_of
from tests.conftest import needs_sandbox
from tests.kit.reallab import RealLab, real_lab
from viewers.web.robot_panel import NONE

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

GOOD = """\
from common.controller import Controller, Khepera


class Circle(Controller):
    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        print("left_speed=[3, 4] *fast* #1 <b>x</b>")

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(8, 4)
"""
PRINTED = "left_speed=[3, 4] *fast* #1 <b>x</b>"
PLANTED = GOOD.replace("robot.set_speeds(8, 4)", "robot.set_speed(8, 4)")  # line 11


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("workbench")), agents=True, slot=600.0) as env:
        yield env


def write_code(page: ViserPage, text: str, wait_for: object) -> None:
    """Put ``text`` in the code editor as a paste does (typing would auto-indent it)."""
    page.p.get_by_role("textbox", name="Controller code", exact=True).wait_for(timeout=15_000)
    page.p.evaluate(
        "text => { const v = window.wartEditor.editorFor(null).view;"
        " v.dispatch({changes: {from: 0, to: v.state.doc.length, insert: text}}); }",
        text,
    )
    wait_until(lambda: wait_for() is True, 10, what="the editor's text on the server")  # type: ignore[operator]


def test_write_check_fix_run_see_it_move_reset_and_stop(open_page, lab: RealLab) -> None:
    alice = open_page("alice")
    panel = enter_arena(alice, lab, "alice")
    bench = panel.workbench
    assert bench is not None
    view = session_of(lab.viewer, "alice").view
    wait_until(lambda: view.frames_applied > 3, 15, what="the arena's frames in alice's view")

    # A planted error: Check names its line and marks it beside the code.
    write_code(alice, PLANTED, lambda: bench.code.value == PLANTED)
    alice.click("Check")
    alice.wait_text("line 11: robot.set")
    alice.wait_text("does not exist on Khepera (did you mean set")
    assert "&gt;&gt; 11 |         robot.set_speed(8, 4)" in bench.problems.content
    alice.wait_text(">> 11 |")
    marker = alice.p.locator(".cm-lint-marker-error")  # and in the gutter (within 150 ms)
    marker.first.wait_for(timeout=10_000)
    assert marker.count() == 1
    alice.screenshot("workbench-check-names-the-line")
    # Run refuses a file Check finds wrong: nothing is queued. The robot is chosen
    # beside the editor's buttons; the robot panel's list follows.
    choose(alice, "Run on", "k0")
    assert panel.robots is not None
    wait_until(lambda: panel.robots.robot.value == "k0", 10, what="the panel following Run on")
    alice.click("Run in simulation")
    alice.wait_text("Not queued: fix the problems Check found first")

    # Fixed: Check is clean, the run queues on k0 and the robot moves in the world.
    write_code(alice, GOOD, lambda: bench.code.value == GOOD)
    alice.click("Check")
    alice.wait_text("Check: no problems found")
    assert view.feed is not None
    start = view.feed.latest()
    assert start is not None
    k0 = view.robot_names.index("k0")
    alice.click("Run in simulation")
    # Queued, then running at once (nobody waits for k0): the status says the latter.
    alice.wait_text("Your controller runs on k0", timeout=15_000)

    def k0_moved() -> bool:
        frame = view.feed.latest() if view.feed else None
        return frame is not None and bool(
            np.hypot(*(frame.poses[k0, :2] - start.poses[k0, :2])) > 30
        )

    wait_until(k0_moved, 20, what="k0 driven by the editor's controller")
    # The print is shown exactly as printed: no markdown, no HTML, no backslashes.
    printed = alice.p.locator("pre.wart-output", has_text=PRINTED)
    printed.first.wait_for(timeout=15_000)
    assert f"k0 alice: {PRINTED}" in printed.first.inner_text().splitlines()
    assert printed.first.locator("b", has_text="x").count() == 0  # <b> was text, not markup
    alice.screenshot("workbench-running")
    # The file is kept by the lab, under alice's name: it is in her list.
    assert "mine: my_controller.py" in bench.start_from.options
    assert [f.name for f in bench.connection.list_files(bench.ctx)] == ["my_controller.py"]

    # Reset while she holds k0: the world puts it back at its start pose.
    alice.click("Reset")
    alice.wait_text("Reset: k0 is back at")

    # Stop ends her controller; the context says so and k0 comes to rest.
    alice.click("Stop")
    # "Stopped: ..." at once, then the context's word that the run ended replaces it.
    alice.wait_text("Your controller on k0 cancelled", timeout=15_000)
    seen: list[np.ndarray] = []

    def k0_at_rest() -> bool:
        frame = view.feed.latest() if view.feed else None
        if frame is None:
            return False
        seen.append(frame.poses[k0, :2].copy())
        # Still over the last ten frames the page converted (about 0.4 s of frames).
        recent = seen[-10:]
        return len(recent) == 10 and float(np.ptp(np.asarray(recent), axis=0).max()) < 1.0

    wait_until(k0_at_rest, 15, what="k0 at rest after Stop")
    alice.screenshot("workbench-stopped")


def test_queue_on_the_real_robot_without_a_real_arena_says_what_to_do(
    open_page, lab: RealLab
) -> None:
    bob = open_page("bob")
    panel = enter_arena(bob, lab, "bob")
    assert panel.workbench is not None
    bob.click("Queue on the real robot")
    bob.wait_text("You have not joined a real arena")
    # Keyboard only: Tab reaches the editor's buttons, each named by its text.
    bob.button("Check").focus()
    bob.p.keyboard.press("Enter")
    bob.wait_text("Check: no problems found")


INTO_THE_WALL = """\
from common.controller import Controller, Khepera


class Charge(Controller):
    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(127, 127)
"""


def test_the_editors_dry_run_warns_of_a_controller_that_charges_a_wall(
    open_page, lab: RealLab
) -> None:
    carol = open_page("carol")
    panel = enter_arena(carol, lab, "carol")
    bench = panel.workbench
    assert bench is not None and panel.robots is not None
    write_code(carol, INTO_THE_WALL, lambda: bench.code.value == INTO_THE_WALL)
    pick_robot(carol, panel, "k3")
    carol.click("Dry run")
    carol.wait_text(
        "on k3: will run, with a warning: 1 collision, the first with a wall", timeout=40_000
    )
    carol.wait_text("wheel commands at top speed")
    carol.screenshot("workbench-dry-run-wall")
    assert "collision at" in bench.problems.content  # what it saw, under the code
    assert all(not r.queue and r.holder is None for r in panel.robots._rows)  # nothing queued


QUEUED = b"""\
from common.controller import Controller, Khepera


class Spin(Controller):
    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(-5, 5)
"""


def test_the_editors_stop_ends_a_run_started_by_queue_with_no_robot_chosen(
    open_page, lab: RealLab
) -> None:
    bob = open_page("bob")
    panel = enter_arena(bob, lab, "bob")
    bench, robots = panel.workbench, panel.robots
    assert bench is not None and robots is not None
    # Queued from the robot panel (not the editor): the run is on k2.
    pick_robot(bob, panel, "k2")
    wait_until(lambda: bench.target.value == "k2", 10, what="Run on following the panel")
    upload(bob, "spin.py", QUEUED)
    bob.wait_text("spin.py is queued for k2")

    def mine() -> list[tuple[str, int | None]]:
        return [
            (r.agent, r.my_position) for r in bench.connection.agents(bench.ctx) if r.my_request
        ]

    wait_until(lambda: mine() == [("k2", 0)], 20, what="bob's run on k2")
    # No robot chosen anywhere: the editor's Stop still finds and ends it.
    choose(bob, "Run on", NONE)
    wait_until(lambda: bench.target.value == NONE, 10, what="Run on emptied")
    bob.click("Stop")
    # The editor follows a run of bob's queued elsewhere (here, the robot panel): its end shows.
    bob.wait_text("Your controller on k2 cancelled", timeout=15_000)
    wait_until(lambda: mine() == [], 15, what="bob's run on k2 ended by Stop")

    # "Cancel my request" with one request and no robot chosen cancels it too.
    pick_robot(bob, panel, "k2")  # "(none)" in Run on emptied the panel's choice too
    upload(bob, "spin2.py", QUEUED)
    bob.wait_text("spin2.py is queued for k2")
    wait_until(lambda: mine() == [("k2", 0)], 20, what="bob's second run on k2")
    pick_robot(bob, panel, NONE)
    bob.click("Cancel my request")
    wait_until(lambda: mine() == [], 15, what="bob's run cancelled from the robot panel")
