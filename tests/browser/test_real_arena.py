"""The real arena in the page: the camera's video under the robot, the robot at its tracked
pose (within millimetres of where it really is, while its odometry drifts), and a camera
that goes away said in words.

A real lab (router, registry, room, engine) plus the real arena `wart up` runs without
hardware: an emulated Khepera with slipping wheels behind a bridge, and a synthetic camera
rendering the emulator's true poses. The viewer runs in the test, so the test reads what
it drew and sent to this browser; the DOM says what the page says.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.tracking.truth import read_truth
from tests.browser.conftest import wait_until
from tests.browser.test_real_lab import log_in, session_of
from tests.conftest import needs_sandbox
from tests.kit.agentkit import start_agent_context, start_runner
from tests.kit.pages import describe_view
from tests.kit.reallab import WORLD, RealLab, real_lab
from viewers.web.ghost import GHOST_NODE
from viewers.web.tabs import tab_label
from viewers.web.world_feed import RobotReadings
from viewers.web.world_view import WorldView

pytestmark = [pytest.mark.integration, pytest.mark.real_lab]
REAL = "real1"
RUNS = "realruns"  # the real arena's agent context


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("realarena")), real_arena=REAL) as env:
        yield env


def truth_of(lab: RealLab) -> tuple[float, float, float]:
    truth = read_truth(lab.lab.wiring().state_dir / "dev" / f"{REAL}-truth.json")
    return truth.robots["k1"]


def test_the_real_arena_shows_its_video_and_the_robot_where_it_is(open_page, lab: RealLab) -> None:
    page = open_page("ida")
    log_in(page, lab, "ida")
    page.click(f"Join {REAL}")
    browser = session_of(lab.viewer, "ida")
    view, video = browser.view, browser.video
    wait_until(lambda: view.snapshot is not None and view.snapshot.real, 30, what="the real arena")
    wait_until(lambda: video.shown >= 0, 60, what="the camera's video drawn under the world")
    node = video.image
    assert node is not None
    assert tuple(node.position) == pytest.approx((0.5, 0.5, -0.0005))  # centred on the arena
    with lab.driving("k1", speeds=(8, 12), world=REAL):
        first = video.shown
        # Driving for 20 s: the camera's frames keep coming to this browser.
        wait_until(lambda: video.shown >= first + 20, 60, what="20 new video frames")
        start = truth_of(lab)
        # The wheels' speeds the robot's odometry reads reach the page (what the twin's
        # ghost predicts from) through the viewer's own grant on k1's sensor sample.
        feed = view.feed
        assert feed is not None
        wait_until(lambda: wheels(feed.sensors("k1")) == (8, 12), 30, what="k1's wheel speeds")
        wait_until(
            lambda: math.dist(truth_of(lab)[:2], start[:2]) > 100, 60, what="k1 to drive 100 mm"
        )
    wait_until(
        lambda: error_mm(view, lab) < 10.0, 15, what="k1 drawn within 10 mm of its true pose"
    )
    assert video.said == "", f"the page says: {video.said}"
    page.screenshot("real-arena-video")


def wheels(readings: RobotReadings | None) -> tuple[int, ...]:
    return () if readings is None else tuple(int(v) for v in readings.speeds)


def drawn_mm(view: WorldView) -> tuple[float, float]:
    drawn = view.drawn_positions()
    assert drawn is not None and len(drawn) == 1
    return float(drawn[0][0]) * 1000.0, float(drawn[0][1]) * 1000.0


def error_mm(view: WorldView, lab: RealLab) -> float:
    x, y = drawn_mm(view)
    tx, ty, _ = truth_of(lab)
    return math.hypot(x - tx, y - ty)


def test_a_camera_that_stops_is_said_on_the_page(open_page, lab: RealLab) -> None:
    page = open_page("bob")
    log_in(page, lab, "bob")
    page.click(f"Join {REAL}")
    video = session_of(lab.viewer, "bob").video
    wait_until(lambda: video.shown >= 0, 60, what="the camera's video")
    camera = next(p for p in lab.lab.procs.started if p.name.startswith("camera"))
    camera.kill9()
    wait_until(lambda: "stopped answering" in video.said, 30, what="the viewer to notice")
    page.wait_text("camera offline: it has stopped answering", timeout=30_000)
    page.screenshot("real-arena-camera-offline")


def test_the_view_follows_the_arena_tab_in_front(open_page, lab: RealLab) -> None:
    """Two arenas joined: clicking one's tab shows its world, with nothing of the other
    (its selected robot's rays and trail) left drawn."""
    page = open_page("bob")
    log_in(page, lab, "bob")
    page.click(f"Join {REAL}")
    browser = session_of(lab.viewer, "bob")
    view = browser.view

    def showing() -> str | None:
        snap, feed = view.snapshot, view.feed
        if snap is None or feed is None:
            return None
        return REAL if snap.real else "sim"

    wait_until(lambda: showing() == REAL, 30, what="the real arena shown on joining it")
    # The simulated world has no context of its own: opened as the address bar opens one.
    browser.connect(f"{lab.address.with_user('bob').url()}/{WORLD}")
    wait_until(lambda: showing() == "sim", 30, what="the simulated world shown on joining it")
    # Its robots and frames drawn first: a click selects only a robot the page shows
    # (under load the snapshot came before the robots' names, and a select then chose
    # nothing), and a trail grows from the frames drawn after the selection (every fifth).
    wait_until(
        lambda: len(view.robot_names) > 0 and view.drawn is not None,
        30,
        what=lambda: f"the simulated world's robots and a frame drawn ({describe_view(view)})",
    )
    view.select(0)  # a robot of the simulated world selected: its trail drawn
    wait_until(
        lambda: view._trail_handle is not None,
        30,
        what=lambda: f"the selected robot's trail ({describe_view(view)})",
    )
    page.tab(f"{REAL} (arena)").last.click()
    wait_until(lambda: showing() == REAL, 30, what="the real arena back when its tab is clicked")
    assert view.selected is None and view._rays is None and view._trail_handle is None
    page.tab(f"{WORLD} (arena)").last.click()
    wait_until(lambda: showing() == "sim", 30, what="the simulated world when its tab is clicked")
    # A tab that is not an arena's (the lab's lobby) leaves the view where it was.
    page.tab(tab_label(lab.address)).first.click()
    lobby = tab_label(lab.address)
    wait_until(lambda: lobby in browser.front.labels, 15, what="the lobby tab in front")
    assert showing() == "sim"


STEADY = b'''"""Drives on a steady curve."""

from common.controller import Controller, Khepera


class Steady(Controller):
    period = 0.1

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(8, 12)
'''


@pytest.fixture(scope="module")
def run_desk(lab: RealLab) -> str:
    """The real arena's agent context (owner ida) and a runner: where runs on k1 are asked
    for from the page. Started for the last test only: once the arena has a context, the
    lobby joins real1 through it (no "Join real1" button for the tests above)."""
    start_runner(lab.lab)
    start_agent_context(lab.lab, slot=60.0, ctx=RUNS, world=REAL, account=f"ctx-{RUNS}")
    return RUNS


@needs_sandbox
@pytest.mark.timeout(240)  # the runner and agent context start in its setup
def test_the_twins_ghost_is_drawn_ahead_of_a_live_run(
    open_page, lab: RealLab, run_desk: str
) -> None:
    page = open_page("ida")
    log_in(page, lab, "ida")
    page.click(f"Join {run_desk}", timeout=30_000)  # once the new context is in the lobby
    page.tab(f"{run_desk} (arena)").last.click()
    page.wait_text("Upload controller")
    panels = next(iter(session_of(lab.viewer, "ida").labs.values())).panels
    wait_until(lambda: run_desk in panels, 10, what="ida's panel of the real arena")
    robots = panels[run_desk].robots
    assert robots is not None
    page.input_after_label("Robot").click()
    page.p.get_by_role("option", name="k1", exact=True).click()
    wait_until(lambda: robots.robot.value == "k1", 10, what="k1 chosen")
    page.p.locator("input[type=file]").last.set_input_files(
        {"name": "steady.py", "mimeType": "text/x-python", "buffer": STEADY}
    )
    ghost = robots.ghost
    wait_until(lambda: ghost.body is not None, 60, what="the ghost drawn while k1 runs")
    assert ghost.body is not None and ghost.body.name == GHOST_NODE
    # ida owns the arena, so the registry answers her: no twin of k1 is kept.
    page.wait_text("prediction: the datasheet Khepera")
    assert ghost.legend.content == "prediction: the datasheet Khepera"
    first = ghost.anchored
    wait_until(lambda: ghost.anchored > first, 15, what="the ghost re-anchored on a new pose")
    page.p.get_by_label("Show the twin's prediction").uncheck()
    wait_until(lambda: ghost.body is None, 15, what="the ghost hidden by its checkbox")
    page.click("Cancel my request", timeout=30_000)
