"""Join the arena and see the robots move: pixels change, and the page got frames."""

from __future__ import annotations

import io

import numpy as np

from tests.browser.conftest import join_demo_arena, wait_until
from viewers.web.app import WebViewer

# The scene part of the page, left of the docked panel and below viser's
# "Software WebGL rendering detected" notice (top-left), which is masked out.
SCENE_BOX = (0, 170, 860, 800)  # x0, y0, x1, y1 at 1280x800


def scene_pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    image = Image.open(io.BytesIO(png)).convert("RGB")
    return np.asarray(image.crop(SCENE_BOX), np.int16)


def test_arena_robots_move(open_page, viewer: WebViewer) -> None:
    page, session = join_demo_arena(open_page, viewer, "ana")
    view = session.view
    wait_until(lambda: view.frames_applied > 10, what="frames to reach the view")

    # Frames reach the page: the robots' pixels differ between two screenshots.
    page.draw()
    first = page.p.screenshot()
    n0 = view.frames_applied
    wait_until(lambda: view.frames_applied > n0 + 12, what="more frames")
    second = page.p.screenshot()
    (page.screenshot("arena"))
    changed = np.abs(scene_pixels(first) - scene_pixels(second)).sum(axis=2) > 30
    assert changed.sum() > 200, f"only {changed.sum()} pixels changed: are robots drawn?"

    # Selecting a robot (as a click would) gives it a trail and the robot panel its name.
    view.select(0)
    page.tab("arena").last.click()
    page.wait_text("Selected: k0")
    wait_until(lambda: view._trail_handle is not None, what="a trail for the selected robot")
    page.screenshot("selected")
