"""The follow camera and the world view's checkboxes, in Chromium on the demo lab.

"Follow the selected robot" keeps the selected robot in the middle of this
browser's view: the server moves the client's camera at the pump's slow tick
(5 Hz), and the browser reports its camera back; the test reads those reports
(``client.camera.on_update``), so what it checks is where the page's camera
looks, not only what the server asked for. Both checkboxes are used from the
keyboard only (Tab to reach, Space to toggle).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator

import numpy as np
import pytest

from tests.browser.conftest import join_demo_arena, show_still_frame, wait_until
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoLab


@pytest.fixture
def fake_lab() -> Iterator[DemoLab]:
    lab = DemoLab("Test lab", robots=6)
    lab.worlds["arena"].stop()  # frames only when the test makes one
    yield lab
    lab.close()


def test_the_camera_follows_the_selected_robot(
    open_page, viewer: WebViewer, fake_lab: DemoLab
) -> None:
    page, session = join_demo_arena(open_page, viewer, "ana")
    view = session.view
    world = fake_lab.worlds["arena"]
    frame = show_still_frame(world, view)  # the camera's height below is the aimed one

    reports: list[tuple[np.ndarray, np.ndarray]] = []
    lock = threading.Lock()

    def reported(camera) -> None:  # the browser's own camera, as it reports it
        with lock:
            reports.append((np.array(camera.position), np.array(camera.look_at)))

    view.client.camera.on_update(reported)
    height = float(view.client.camera.position[2])
    name = view.robot_names[3]
    view.select(3)  # as a click on it would
    page.tab("arena").last.click()
    page.wait_text(f"Selected: {name}")

    # Keyboard only: Tab from "Show IR rays" reaches the follow box; Space ticks each.
    rays = page.p.get_by_label("Show IR rays")
    rays.focus()
    page.p.keyboard.press("Space")
    wait_until(lambda: view.show_rays, what="IR rays on, from the keyboard")
    page.p.keyboard.press("Tab")
    follow = page.p.get_by_label("Follow the selected robot")
    assert follow.evaluate("el => el === document.activeElement")
    page.p.keyboard.press("Space")
    wait_until(lambda: view.follow, what="following, from the keyboard")

    def looks_at(pose_mm: np.ndarray) -> bool:
        with lock:
            if not reports:
                return False
            position, look = reports[-1]
        target = pose_mm[:2] * geo.MM
        return bool(
            np.hypot(*(look[:2] - target)) < 0.005  # within 5 mm of the robot's centre
            and np.hypot(*(position[:2] - target)) < 0.005  # straight above it
            and abs(position[2] - height) < 0.01  # at the height it had
        )

    wait_until(lambda: looks_at(frame.poses[3]), what="the page's camera on the robot")
    page.screenshot("follow-1")
    # The robot moves on: the camera goes with it.
    later = world.produce(5.0)
    assert np.hypot(*(later.poses[3, :2] - frame.poses[3, :2])) > 50
    wait_until(lambda: looks_at(later.poses[3]), what="the page's camera after the robot moved")
    page.screenshot("follow-2")

    # Off: the robot moves again, the camera stays where it was.
    follow.focus()
    page.p.keyboard.press("Space")
    wait_until(lambda: not view.follow, what="following off")
    still = np.array(view.client.camera.look_at)
    moved = world.produce(8.0)
    wait_until(lambda: view.last_seq == moved.seq, what="the last frame in the view")
    for _ in range(3):  # three slow ticks of the pump (5 Hz), counted, not slept
        ticks = viewer.pump.ticks
        wait_until(lambda t=ticks: viewer.pump.ticks >= t + 5, what="a slow tick")
    assert np.array(view.client.camera.look_at) == pytest.approx(still)
