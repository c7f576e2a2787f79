"""A swarm too big for meshes is drawn as points, and a click on one still selects it.

Past POINTS_FROM robots the bodies are one point cloud (the page then paints
about six times as many frames a second at 10,000 robots: docs/BENCHMARKS.md),
which viser cannot pick: the view finds the robot where the click's ray meets
the floor. The test clicks where a robot is drawn, as a student would.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator

import numpy as np
import pytest
import viser

from tests.browser.conftest import join_demo_arena, screen_points, show_still_frame, wait_until
from tests.browser.test_robot_heading import NOTICES
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoLab, DemoWorld
from viewers.web.world_view import FLOOR_COLOUR, POINTS_FROM

ROBOTS = POINTS_FROM + 500
SIDE_MM = 6000.0  # 120 mm between homes: a robot (55 mm) with floor around it


@pytest.fixture
def fake_lab() -> Iterator[DemoLab]:
    lab = DemoLab("Test lab", robots=1)
    lab.worlds["arena"].stop()
    # Frames only when the test makes one: the robots hold still under the mouse.
    lab.worlds["arena"] = DemoWorld("arena", ROBOTS, width=SIDE_MM, height=SIDE_MM, start=False)
    yield lab
    lab.close()


def test_a_swarm_is_drawn_as_points_and_a_click_selects_a_robot(
    open_page, viewer: WebViewer, fake_lab: DemoLab
) -> None:
    from PIL import Image

    page, session = join_demo_arena(open_page, viewer, "ana")
    view = session.view
    frame = show_still_frame(fake_lab.worlds["arena"], view, 15)
    assert isinstance(view._robots, viser.PointCloudHandle)
    assert np.asarray(view._robots.points)[:, :2] * 1000 == pytest.approx(
        frame.poses[:, :2], abs=0.5
    )

    # The page draws the robots where the frame puts them, and floor between them.
    page.draw()
    floor = np.array(FLOOR_COLOUR, np.int16)
    looks: dict[str, np.ndarray] = {}

    def on_screen() -> np.ndarray:
        """Some 40 robots well inside the canvas, by the camera and canvas of this moment.

        Computed at each look, not once: under load the page may still be laying out
        its panel or settling its camera when the first frame arrives.
        """
        box = page.p.locator("canvas").first.bounding_box()
        centre = screen_points(page, view, frame.poses[:, :2])
        inside = (
            (centre[:, 0] > max(box["x"], NOTICES[0]) + 10)
            & (centre[:, 0] < box["x"] + box["width"] - 10)
            & (centre[:, 1] > max(box["y"], NOTICES[1]) + 10)
            & (centre[:, 1] < box["y"] + box["height"] - 10)
        )
        return np.flatnonzero(inside)[:: max(1, int(inside.sum()) // 40)]

    def robots_shown() -> bool:
        png = page.p.screenshot()
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)
        picked = on_screen()
        points = screen_points(page, view, frame.poses[picked, :2])
        ix, iy = np.rint(points).astype(int).T
        ok = (ix >= 0) & (ix < image.shape[1]) & (iy >= 0) & (iy < image.shape[0])
        if len(picked) < 20 or not ok.all():
            return False  # the camera moved between the screenshot and its report
        looks["picked"] = picked
        looks["at"] = np.abs(image[iy, ix] - floor).sum(axis=1)
        return bool((looks["at"] > 60).mean() >= 0.9)

    with contextlib.suppress(AssertionError):
        wait_until(robots_shown, 15, what="the swarm's robots drawn")
    page.screenshot("swarm-points")
    assert "at" in looks, "the arena's robots never came fully inside the canvas"
    assert (looks["at"] > 60).mean() >= 0.9, f"robots not drawn where they are: {looks['at']}"
    picked = looks["picked"]

    # A click on a robot selects that robot.
    target = int(picked[len(picked) // 2])
    x, y = screen_points(page, view, frame.poses[[target], :2])[0]
    page.p.mouse.click(float(x), float(y))
    wait_until(lambda: view.selected is not None, 10, what="a robot selected by the click")
    assert view.selected == target, f"clicked k{target}, selected k{view.selected}"
    page.screenshot("swarm-clicked")
