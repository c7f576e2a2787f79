"""The arena fits the view beside the panel, at a laptop's and a desktop's screen size.

Decided by geometry, not pixels: the page reports its camera (position, field of
view); the canvas's box comes from the DOM. Each corner of the arena is projected
to the page and must land on the canvas itself (``elementFromPoint``), not under
the docked panel nor off the window.
"""

from __future__ import annotations

import math

import pytest
from playwright.sync_api import expect

from tests.browser.conftest import (
    ViserPage,
    new_test_context,
    page_url,
    wait_for_aimed_camera,
    wait_until,
)
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoLab
from viewers.web.demo_world import DemoWorld

pytestmark = pytest.mark.browser

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
    context = new_test_context(chromium, {"width": size[0], "height": size[1]})
    try:
        page = context.new_page()  # type: ignore[attr-defined]
        vp = ViserPage(page, f"{request.node.name}")
        page.goto(page_url(viewer.url))
        vp.wait_ready()
        vp.log_in("127.0.0.1", "ana", "ana-pw")
        vp.click("Join arena")
        session = next(iter(viewer.sessions.values()))
        wait_until(lambda: session.view.snapshot is not None, what="the arena in the view")
        wait_for_aimed_camera(session.view)
        cam = session.client.camera
        left, top, width, height = page.evaluate(CANVAS_JS)
        assert left + width <= size[0] and height > 0
        corners = ((0, 0), (arena[0], 0), (0, arena[1]), (arena[0], arena[1]))

        def misplaced() -> list[str]:
            """The corners not on the canvas, by the camera the page last reported (a report
            from before the aim can still arrive after it on a busy machine: waited out)."""
            x0, y0, h = cam.position
            half_v = h * math.tan(cam.fov / 2)
            half_h = half_v * width / height
            wrong = []
            for wx, wy in corners:
                nx = (wx * geo.MM - x0) / half_h
                ny = (wy * geo.MM - y0) / half_v
                px = left + (nx + 1) / 2 * width
                py = top + (1 - ny) / 2 * height
                if not (-1.0 < nx < 1.0 and -1.0 < ny < 1.0):
                    wrong.append(f"corner {wx, wy} off the view ({nx:.2f}, {ny:.2f})")
                elif page.evaluate(HIT_JS, [px, py]) != "CANVAS":
                    wrong.append(f"corner {wx, wy} at {px:.0f}, {py:.0f} not on the canvas")
            return wrong

        wait_until(lambda: not misplaced(), what="every corner of the arena on the canvas")
        # Join took the page to the arena's tab (the screenshot is for a person to look at).
        expect(vp.tab("arena (arena)").last).to_have_attribute(
            "aria-selected", "true", timeout=15_000
        )
        vp.screenshot(f"arena-{arena[0]:.0f}x{arena[1]:.0f}-at-{size[0]}x{size[1]}")
    finally:
        context.close()  # type: ignore[attr-defined]
