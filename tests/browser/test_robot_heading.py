"""From above, every robot shows which way it faces: an arrow in a colour of its own.

The arrow is a second batched mesh (one for all robots, like the bodies), so
the test checks both what the server sends and what the page shows: just
ahead of each robot's centre the arrow's colour (dark; red while an LED is
lit), just behind it the body's colour.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Iterator

import numpy as np
import pytest

from tests.browser.conftest import join_demo_arena, screen_points, show_still_frame, wait_until
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoLab
from viewers.web.prepared_frame import HEADING_DARK, HEADING_LIT

ROBOTS = 16  # more than LABEL_ALL_UP_TO: no name labels over the robots
NOTICES = (330, 300)  # viser's notifications cover the page's top-left corner up to (x, y)


@pytest.fixture
def fake_lab() -> Iterator[DemoLab]:
    lab = DemoLab("Test lab", robots=ROBOTS)
    lab.worlds["arena"].stop()  # frames only when the test makes one: robots hold still
    yield lab
    lab.close()


def test_heading_arrow_is_drawn_in_its_own_colour(
    open_page, viewer: WebViewer, fake_lab: DemoLab
) -> None:
    from PIL import Image

    page, session = join_demo_arena(open_page, viewer, "ana")
    page.draw()  # this test reads the drawn pixels
    view = session.view
    frame = show_still_frame(fake_lab.worlds["arena"], view)

    # What the server sends: one batched mesh of arrows beside the bodies, placed and
    # turned as the robots are, coloured by LED state rather than like the bodies.
    bodies, arrows = view._robots, view._headings
    assert bodies is not None and arrows is not None and arrows is not bodies
    assert np.asarray(arrows.batched_positions)[:, :2] * 1000 == pytest.approx(
        frame.poses[:, :2], abs=0.1
    )
    for wxyz, pose in zip(np.asarray(arrows.batched_wxyzs), frame.poses, strict=True):
        turn = geo.wxyz_to_yaw(wxyz) - float(pose[2])
        assert math.remainder(turn, 2 * math.pi) == pytest.approx(0.0, abs=1e-4)
    lit = frame.leds != 0
    assert 0 < lit.sum() < ROBOTS  # the demo lights some LEDs: both colours are seen
    expected = np.where(lit[:, None], HEADING_LIT, HEADING_DARK)
    assert (np.asarray(arrows.batched_colors) == expected).all()

    # What the page shows.
    radius_mm = view.snapshot.robot_radius
    heading = np.stack([np.cos(frame.poses[:, 2]), np.sin(frame.poses[:, 2])], axis=1)
    looks: dict[str, np.ndarray] = {}  # the last look: where, and what the page showed there

    def pixels_at(image: np.ndarray, points: np.ndarray) -> np.ndarray:
        ix, iy = np.rint(points).astype(int).T
        return image[iy, ix]

    def bodies_and_arrows_shown() -> bool:
        # The points are taken afresh at every look, from the canvas's box and the
        # camera of that moment, so a page still laying itself out is followed. (With
        # points taken once before the first look, one robot's body read white twice
        # in runs beside busy loops; whether the page had moved is not known.)
        centre = screen_points(page, view, frame.poses[:, :2])
        ahead = screen_points(page, view, frame.poses[:, :2] + 0.25 * radius_mm * heading)
        behind = screen_points(page, view, frame.poses[:, :2] - 0.7 * radius_mm * heading)
        seen = ~((centre[:, 0] < NOTICES[0]) & (centre[:, 1] < NOTICES[1]))
        png = page.p.screenshot()
        image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)
        front, back = pixels_at(image, ahead[seen]), pixels_at(image, behind[seen])
        looks.update(seen=seen, front=front, back=back)
        greyness = np.abs(back - back.mean(axis=1, keepdims=True)).max(axis=1)
        return bool((greyness > 20).all() and (np.abs(front - back).sum(axis=1) > 150).all())

    # The page draws the two meshes as their messages arrive, not always in the same
    # frame: look until both show; the assertions below say what is wrong.
    with contextlib.suppress(AssertionError):
        wait_until(bodies_and_arrows_shown, 15, what="every robot's body and arrow")
    seen, front, back = looks["seen"], looks["front"], looks["back"]
    assert seen.sum() >= ROBOTS // 2
    page.screenshot("headings")
    # The floor is a light grey: a robot's body, where the frame puts it, is not.
    greyness = np.abs(back - back.mean(axis=1, keepdims=True)).max(axis=1)
    assert (greyness > 20).all(), f"no robot body behind some centres: {back}"
    apart = np.abs(front - back).sum(axis=1)
    assert (apart > 150).all(), f"arrow and body look alike: {apart}"
    for colour, on in zip(front, lit[seen], strict=True):
        r, g, b = (int(v) for v in colour)
        if on:
            assert r > g + 100 and r > b + 100, f"a lit robot's arrow is red, not {colour}"
        else:
            assert max(r, g, b) < 90, f"an arrow is dark, not {colour}"
