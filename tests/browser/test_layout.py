"""The arena fits the view beside the panel, at a laptop's and a desktop's screen size.

Decided by geometry, not pixels: the page reports its camera (position, field of
view); the canvas's box comes from the DOM. Each corner of the arena is projected
to the page and must land on the canvas itself (``elementFromPoint``), not under
the docked panel nor off the window.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import (
    ViserPage,
    new_test_context,
    wait_for_aimed_camera,
    wait_until,
)
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.client import BrowserSession
from viewers.web.demo_lab import DemoLab
from viewers.web.demo_world import DemoWorld

CANVAS_JS = """() => {
  const all = [...document.querySelectorAll('canvas')];
  const c = all.sort((a, b) => b.clientWidth * b.clientHeight - a.clientWidth * a.clientHeight)[0];
  const r = c.getBoundingClientRect();
  return [r.left, r.top, r.width, r.height];
}"""
# What is drawn at a point, passing over notifications (a toast fades away; headless
# Chromium's "software WebGL" notice sits at the top left for a while).
HIT_JS = """([x, y]) => {
  const hits = document.elementsFromPoint(x, y).filter(
    (e) => !e.closest('[role=alert], [class*=Notification]'));
  return hits.length ? hits[0].tagName : '';
}"""


def misplaced(page: object, cam: object, arena: tuple[float, float]) -> list[str]:
    """The arena's corners not on the canvas, by the camera the page last reported (a report
    from before the aim can still arrive after it on a busy machine: waited out)."""
    left, top, width, height = page.evaluate(CANVAS_JS)  # type: ignore[attr-defined]
    x0, y0, h = cam.position  # type: ignore[attr-defined]
    half_v = h * math.tan(cam.fov / 2)  # type: ignore[attr-defined]
    half_h = half_v * width / height
    wrong = []
    for wx, wy in ((0, 0), (arena[0], 0), (0, arena[1]), (arena[0], arena[1])):
        nx = (wx * geo.MM - x0) / half_h
        ny = (wy * geo.MM - y0) / half_v
        px = left + (nx + 1) / 2 * width
        py = top + (1 - ny) / 2 * height
        if not (-1.0 < nx < 1.0 and -1.0 < ny < 1.0):
            wrong.append(f"corner {wx, wy} off the view ({nx:.2f}, {ny:.2f})")
        elif page.evaluate(HIT_JS, [px, py]) != "CANVAS":  # type: ignore[attr-defined]
            wrong.append(f"corner {wx, wy} at {px:.0f}, {py:.0f} not on the canvas")
    return wrong


@contextmanager
def _in_the_arena(
    chromium: object, viewer: WebViewer, request: pytest.FixtureRequest, size: tuple[int, int]
) -> Iterator[tuple[ViserPage, BrowserSession]]:
    """ana's page in a window of ``size``, logged in and joined to the arena, its camera
    aimed; the browser context is closed after."""
    context = new_test_context(chromium, {"width": size[0], "height": size[1]})
    try:
        page = context.new_page()  # type: ignore[attr-defined]
        vp = ViserPage(page, f"{request.node.name}")
        vp.open(viewer.url)
        vp.log_in("127.0.0.1", "ana", "ana-pw")
        vp.click("Join arena")
        session = next(iter(viewer.sessions.values()))
        wait_until(lambda: session.view.snapshot is not None, what="the arena in the view")
        wait_for_aimed_camera(session.view)
        yield vp, session
    finally:
        context.close()  # type: ignore[attr-defined]


@pytest.mark.parametrize("size", [(1280, 800), (1920, 1080)])
@pytest.mark.parametrize("arena", [(2000.0, 2000.0), (3000.0, 1200.0)])
def test_the_whole_arena_is_on_the_canvas_beside_the_panel(
    chromium: object,
    viewer: WebViewer,
    fake_lab: DemoLab,
    request: pytest.FixtureRequest,
    size: tuple[int, int],
    arena: tuple[float, float],
) -> None:
    old = fake_lab.worlds["arena"]
    fake_lab.worlds["arena"] = DemoWorld("arena", 4, width=arena[0], height=arena[1])
    old.stop()
    with _in_the_arena(chromium, viewer, request, size) as (vp, session):
        page = vp.p
        left, _top, width, height = page.evaluate(CANVAS_JS)
        assert left + width <= size[0] and height > 0
        wait_until(
            lambda: not misplaced(page, session.client.camera, arena),
            what="every corner of the arena on the canvas",
        )
        # Join took the page to the arena's tab (the screenshot is for a person to look at).
        expect(vp.tab("arena (arena)").last).to_have_attribute(
            "aria-selected", "true", timeout=15_000
        )
        vp.screenshot(f"arena-{arena[0]:.0f}x{arena[1]:.0f}-at-{size[0]}x{size[1]}")


GRIP_JS = """() => getComputedStyle(
  document.querySelector('[data-dock-region-resize]'), '::after').content"""


def test_on_a_laptop_code_and_output_are_in_view_together_and_the_panel_widens(
    chromium: object, viewer: WebViewer, request: pytest.FixtureRequest
) -> None:
    """1280x800: the editor and its run's output fit the window at once; the panel's edge
    shows a grip, dragging it widens the panel, and the arena is fitted again beside it."""
    with _in_the_arena(chromium, viewer, request, (1280, 800)) as (vp, session):
        page = vp.p
        arena = (session.view.snapshot.width, session.view.snapshot.height)  # type: ignore[union-attr]

        editor = page.locator(".wart-editor .cm-editor").first
        editor.wait_for(timeout=15_000)
        editor.evaluate("e => e.scrollIntoView({block: 'start'})")
        output = page.locator(".wart-run-output").first
        code_box, out_box = editor.bounding_box(), output.bounding_box()
        assert code_box is not None and out_box is not None
        assert code_box["y"] >= 0 and out_box["y"] + out_box["height"] <= 800, (code_box, out_box)

        assert page.evaluate(GRIP_JS) == '""'  # the grip is drawn
        grip = page.locator("[data-dock-region-resize]").first.bounding_box()
        assert grip is not None
        before = page.evaluate(CANVAS_JS)[2]
        x, y = grip["x"] + grip["width"] / 2, 400
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x - 250, y, steps=10)
        page.mouse.up()
        wait_until(
            lambda: page.evaluate(CANVAS_JS)[2] < before - 200, what="the panel 250 px wider"
        )
        wait_until(
            lambda: not misplaced(page, session.client.camera, arena),
            what="the arena fitted again beside the wider panel",
        )
        vp.screenshot("panel-widened")  # for a person (the camera may still be gliding)
