"""Debian's Chromium driven by Playwright: the test browser's settings and a viser page's helpers.

The browser is never downloaded: Playwright launches Debian's Chromium headless
shell (/usr/bin/chromium-headless-shell) with the usual flags (software WebGL).
Screenshots go to test-artifacts/. The browser tests' fixtures
(tests/browser/conftest.py) and the page benchmarks both open their pages
through these.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from tests.kit.procs import REPO
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.client import BrowserSession
from viewers.web.demo_lab import DemoWorld
from viewers.web.world_feed import SceneFrame
from viewers.web.world_view import WorldView

ARTIFACTS = REPO / "test-artifacts"
# Debian's chromium-headless-shell, not the whole browser run headless: it is the
# browser Playwright itself picks for headless pages, and the same Chromium build
# without a window system's parts. A joined page cost 2.71-2.80 s of Chromium's CPU
# in it against 3.12-3.43 s in /usr/bin/chromium --headless (browser process 0.21
# against 0.47 s), interleaved runs of bench.page_load_cost --pages 6 --join --hold 3.
CHROMIUM = Path("/usr/bin/chromium-headless-shell")
# Why the test pages are cheaper to draw than a student's: Debian's Chromium on CI
# renders WebGL in software (SwiftShader, in its GPU process). Measured with three
# pages on a 12-robot arena at 1280x800 (2 cores): the GPU process took 1.4 cores,
# each page drew 3.3 frames a second and a click took 2.3 to 4.5 s (0.1 s before
# the pages joined the arena), because a page draws as many frames as it can and
# each waits behind the others'. A student's browser draws on a GPU. So the test
# browser draws without MSAA (about half a frame's cost: 6.0 frames a second
# against 3.3) and each page at most FRAME_CAP_HZ frames a second, like a slow
# display: every change is still drawn, and the CPU left is the services'.
# The canvas also draws at half the page's pixel density (viser's ``fixedDpr``
# page option; the page's layout and every coordinate stay those of 1280x800):
# one page in a 12-robot arena cost Chromium 0.57 cores at full density and
# 0.36 at half (10 s windows, 2026-11-26), and the three-page agent test, beside
# two busy loops, went from 110-128 s (one run over pytest's 120 s guard) to 82-99 s.
FRAME_CAP_HZ = 5
TEST_PAGE_DPR = 0.5
CHROMIUM_ARGS = [
    "--headless",
    "--webgl-antialiasing-mode=none",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
VIEWPORT = {"width": 1280, "height": 800}  # a laptop screen

# requestAnimationFrame callbacks run together at most FRAME_CAP_HZ times a second
# (three.js's render loop and the page's own animations alike). Playwright's own
# checks (visible, stable) run in an isolated world with the browser's own timer.
FRAME_CAP_SCRIPT = """(() => {
  const raf = window.requestAnimationFrame.bind(window);
  const period = 1000 / HZ;
  let queue = new Map(), nextId = 1, pending = false, last = 0;
  const flush = t => {
    pending = false; last = t;
    const q = queue; queue = new Map();
    for (const cb of q.values()) cb(t);
  };
  window.requestAnimationFrame = cb => {
    const id = nextId++;
    queue.set(id, cb);
    if (!pending) {
      pending = true;
      setTimeout(() => raf(flush), Math.max(0, last + period - performance.now() - 8));
    }
    return id;
  };
  window.cancelAnimationFrame = id => { queue.delete(id); };
})()""".replace("HZ", str(FRAME_CAP_HZ))


# The test pages skip WebGL's draw calls unless asked to draw: SwiftShader's drawing, in
# Chromium's GPU process, was a quarter of Chromium's CPU in the suite (161 of 602 s in a
# CI run; a joined page held 15 s: 8.1 s of CPU drawing, 5.2 s not, by
# bench.page_load_cost). The page itself runs as it does for a student (messages, scene
# graph, React, raycast clicks); only the pixels are not made. A screenshot draws first
# (ViserPage.screenshot), and a test that reads pixels turns drawing on for its page
# (ViserPage.draw). WART_TEST_DRAWS=1 draws always, for watching a run.
DRAWS = os.environ.get("WART_TEST_DRAWS", "") == "1"
_DRAW_SWITCH = """(() => {
  let drawn = 0;
  window.__wartDraws = DRAWS;
  Object.defineProperty(window, "__wartDrawn", { get: () => drawn });
  const calls = ["clear", "drawArrays", "drawElements", "drawArraysInstanced",
                 "drawElementsInstanced", "drawRangeElements"];
  for (const gl of [window.WebGLRenderingContext, window.WebGL2RenderingContext]) {
    for (const name of calls) {
      const real = gl && gl.prototype[name];
      if (!real) continue;
      gl.prototype[name] = function (...args) {
        if (!window.__wartDraws) return undefined;
        drawn += 1;
        return real.apply(this, args);
      };
    }
  }
})()"""


def draw_switch_script(draws: bool) -> str:
    """The init script that skips WebGL's draw calls (``draws`` False) until a page asks."""
    return _DRAW_SWITCH.replace("DRAWS", "true" if draws else "false")


DRAW_SWITCH_SCRIPT = draw_switch_script(DRAWS)


def page_url(url: str) -> str:
    """The viewer's address as the test browser opens it (127.0.0.1, half-density canvas)."""
    url = url.replace("localhost", "127.0.0.1")
    return f"{url}{'&' if '?' in url else '?'}fixedDpr={TEST_PAGE_DPR}"


def launch_chromium(playwright: Any) -> Any:
    """The test browser (CHROMIUM, headless, CHROMIUM_ARGS) from a started Playwright.

    A plain launch gets a fresh temporary profile (user-data-dir) from
    Playwright, deleted on close; Playwright refuses --user-data-dir here.
    """
    return playwright.chromium.launch(
        executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True
    )


def new_test_context(chromium: object, viewport: dict[str, int] | None = None) -> object:
    """A browser context (own cookies and storage) whose pages run at most FRAME_CAP_HZ
    frames a second and skip WebGL's draw calls until asked (DRAW_SWITCH_SCRIPT)."""
    context = chromium.new_context(viewport=viewport or VIEWPORT)  # type: ignore[attr-defined]
    context.add_init_script(FRAME_CAP_SCRIPT)
    context.add_init_script(DRAW_SWITCH_SCRIPT)
    return context


@dataclass
class ViserPage:
    """A viser page in a browser tab, with helpers that find viser's widgets.

    Made before the page is opened, it also sees what the page sends its server
    (:meth:`fill` waits for a typed value to have left the page).
    """

    page: object  # playwright.sync_api.Page
    name: str
    sent: deque[tuple[int, bytes]] = field(default_factory=lambda: deque(maxlen=400))
    sent_count: int = 0  # frames sent so far: their numbers in ``sent``
    received_count: int = 0  # frames the server sent the page
    sockets: int = 0
    console: deque[str] = field(default_factory=lambda: deque(maxlen=20))

    def __post_init__(self) -> None:
        self.page.on("websocket", self._watch)  # type: ignore[attr-defined]
        self.page.on("console", self._note_console)  # type: ignore[attr-defined]

    def _note_console(self, message: Any) -> None:
        if "GL Driver Message" not in message.text:  # software WebGL's, on every page
            self.console.append(f"{message.type}: {message.text}"[:300])

    def _watch(self, ws: object) -> None:
        self.sockets += 1

        def on_sent(payload: bytes | str) -> None:
            data = payload.encode() if isinstance(payload, str) else payload
            self.sent.append((self.sent_count, data))
            self.sent_count += 1

        def on_received(_payload: bytes | str) -> None:
            self.received_count += 1

        ws.on("framesent", on_sent)  # type: ignore[attr-defined]
        ws.on("framereceived", on_received)  # type: ignore[attr-defined]

    @property
    def p(self):
        return self.page

    def open(self, url: str) -> None:
        """The viewer at ``url`` opened as the test browser opens it (page_url), its GUI up."""
        self.page.goto(page_url(url))  # type: ignore[attr-defined]
        self.wait_ready()

    def wait_ready(self, timeout: float = 15_000) -> None:
        # viser's GUI arrives over its websocket once the page is up (the page has
        # more than one canvas, some never visible: wait for the GUI instead).
        self.button("Connect").wait_for(timeout=timeout)

    def input_after_label(self, label: str, nth: int = -1):
        # get_by_label does not find viser inputs (the label's `for` does not match
        # the input id): take the first input or textarea after the label's text.
        xpath = (
            f"xpath=//label[normalize-space(.)='{label}']"
            "/following::*[self::input or self::textarea][1]"
        )
        loc = self.p.locator(xpath)
        return loc.nth(nth) if nth >= 0 else loc.last

    def fill(self, label: str, text: str) -> None:
        """Type ``text`` into the input after ``label``; return once the page has sent it.

        viser 1.1.1's page sends GUI messages through ONE 50 ms throttle that keeps
        only the newest message: a click within the window replaces a typed value
        that had not left yet, and on a busy machine the window's timer fires late.
        The server then acted on the old value (a fresh-clone run hosted a context
        named "" and waited 60 s for its tab). A student typing and clicking on a
        slow laptop can lose a value the same way; a test waits for it to leave.
        """
        box = self.input_after_label(label)
        already = self.sent_count
        unchanged = box.input_value() == text
        # viser sends a text input on each change; no Enter (in the login form it logs in).
        box.fill(text)
        if not text or unchanged or not self.sockets:
            return  # nothing to leave: empty, the value it had, or a page opened before us
        # A text input's message holds the text; a number input's holds a number, and
        # its element carries the widget's uuid, which the message holds too.
        wanted = [text.encode()]
        uuid = box.get_attribute("id") or ""
        if re.fullmatch(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}", uuid):
            wanted.append(uuid.encode())
        deadline = time.monotonic() + 15
        while not any(
            n >= already and any(w in data for w in wanted) for n, data in list(self.sent)
        ):
            if time.monotonic() > deadline:
                raise AssertionError(f"the page did not send what was typed into {label!r}")
            # Playwright's sync API delivers events while it waits, not during a sleep.
            self.p.wait_for_timeout(20)

    def button(self, name: str):
        return self.p.get_by_role("button", name=name, exact=True).last

    def click(self, name: str, timeout: float = 10_000) -> None:
        """Click a button; return once the page has sent the click to its server.

        viser's page sends every GUI message through one 50 ms throttle that keeps
        only the newest (viser/client/src/WebsocketUtils.ts): a click followed within
        the window by another message never leaves on its own. The page's script
        (viewers/web/sure_clicks.py) sends such a click again; a click that still
        has not left after 15 s is the product's failure, pictured and reported.
        """
        button = self.button(name)
        button.wait_for(state="visible", timeout=timeout)
        settle(button, timeout / 1000)
        uuid = (button.get_attribute("id") or "").encode()
        if uuid and self.p.locator(f"[id='file_upload_{uuid.decode()}']").count():
            uuid = b""  # an upload button opens a file chooser; its file is what it sends
        already = self.sent_count
        if uuid:  # marks this element: was the clicked button's node still the page's after?
            button.evaluate("b => { b.dataset.wartClicked = '1'; }")
        received = self.received_count
        button.click(timeout=timeout)
        if not uuid or not self.sockets or self.sent_since(already, uuid, 15.0):
            return
        shot = self.screenshot("click-not-sent")
        raise AssertionError(
            f"the page did not send the click on {name!r} in 15 s ({shot.name}); "
            + self._click_report(uuid.decode(), received)
        )

    def _click_report(self, uuid: str, received: int) -> str:
        """What the page can say of a click that never left: for the next such failure."""
        state = self.p.evaluate(
            """uuid => {
                const b = document.getElementById(uuid);
                return {
                    node: b === null ? 'gone' : b.dataset.wartClicked ? 'same' : 'replaced',
                    disabled: b !== null && b.disabled,
                    sure: window.__wartSureClicks || null,
                };
            }""",
            uuid,
        )
        return (
            f"the button's node after: {state['node']}, disabled {state['disabled']}; "
            f"sure-clicks {state['sure']}; frames received since the click "
            f"{self.received_count - received}, sockets {self.sockets}; "
            f"console: {list(self.console)[-8:]}"
        )

    def sent_since(self, first: int, needle: bytes, timeout: float) -> bool:
        """Has a frame numbered ``first`` or later held ``needle``, within ``timeout`` s?"""
        deadline = time.monotonic() + timeout
        while not any(n >= first and needle in data for n, data in list(self.sent)):
            if time.monotonic() > deadline:
                return False
            # Playwright's sync API delivers events while it waits, not during a sleep.
            self.p.wait_for_timeout(20)
        return True

    def tab(self, name: str):
        return self.p.get_by_role("tab", name=re.compile(re.escape(name)))

    def wait_text(self, text: str, timeout: float = 10_000) -> None:
        self.p.get_by_text(text, exact=False).first.wait_for(timeout=timeout)

    def join_lobby(self) -> None:
        """Join the lab's lobby from the lab's tab and open the lobby's tab."""
        self.click("Join lobby")
        self.tab("lobby").last.click()

    def say(self, line: str) -> None:
        """Send ``line`` to the chat room whose tab is open."""
        self.fill("Message", line)
        self.click("Send")

    def screenshot(self, label: str) -> Path:
        """test-artifacts/<page>-<label>.png, the arena drawn (see DRAW_SWITCH_SCRIPT)."""
        ARTIFACTS.mkdir(exist_ok=True)
        path = ARTIFACTS / f"{self.name}-{label}.png"
        drawing = self.p.evaluate("() => window.__wartDraws")
        if not drawing:
            self.draw()
        try:
            self.p.screenshot(path=str(path))
        finally:
            if not drawing:
                self.draw(False)
        return path

    def draw(self, on: bool = True) -> None:
        """Let the page's WebGL draw (on) until a reload, or skip its draw calls again.

        Turned on, returns once a frame has drawn since (viser draws on demand, and at
        least once a second): a test that reads pixels then reads the scene as it is.
        """
        drawn = self.p.evaluate("on => { window.__wartDraws = on; return window.__wartDrawn; }", on)
        if on:
            # No frame within 5 s: no canvas drew (a page without the scene); the
            # screenshot shows what there is.
            with contextlib.suppress(PlaywrightTimeout):
                self.p.wait_for_function(
                    "n => window.__wartDrawn > n", arg=drawn, polling=100, timeout=5_000
                )

    def open_login(self) -> None:
        """Click Connect and wait for the login form, as a student would.

        A form that never came after a sent click was seen once under load (before
        the page's sure-clicks script, viewers/web/sure_clicks.py); no second click.
        """
        self.click("Connect")
        try:
            self.button("Log in").wait_for(timeout=30_000)
        except PlaywrightTimeout:
            shot = self.screenshot("login-form-missing")
            raise AssertionError(f"no login form 30 s after Connect ({shot.name})") from None

    def log_in(self, address: str, user: str, password: str) -> None:
        self.fill("Address", address)
        self.open_login()
        self.fill("User", user)
        self.fill("Password", password)
        self.click("Log in")


def join_demo_arena(
    open_page: Callable[[str], ViserPage], viewer: WebViewer, user: str
) -> tuple[ViserPage, BrowserSession]:
    """``user``'s page, logged in to the demo lab and in its arena; and the server's view of it.

    The demo lab's passwords are the user's name and ``-pw``. The view is the
    first session's: the tests that use this open one page.
    """
    page = open_page(user)
    page.log_in("127.0.0.1", user, f"{user}-pw")
    page.tab("lab@127.0.0.1").first.click()
    page.click("Join arena")
    session = next(iter(viewer.sessions.values()))
    return page, session


def show_still_frame(world: DemoWorld, view: WorldView, timeout: float = 10.0) -> SceneFrame:
    """One frame of a stopped demo world, once the view has it and the camera is aimed."""
    frame = world.produce(2.0)
    wait_until(lambda: view.last_seq == frame.seq, timeout, what="the test's frame in the view")
    wait_for_aimed_camera(view)
    return frame


def settle(locator: Any, timeout: float = 10.0, quiet_s: float = 0.15) -> None:
    """Return once ``locator``'s box has not moved for ``quiet_s`` (or at ``timeout``).

    Playwright's own check (the same box on two animation frames) passes in the middle of
    a folder's opening on a starved renderer; the panel moved on under the pointer and a
    click landed on the button above ("Add ball" for "Add robot", seen at load 11).
    """
    deadline = time.monotonic() + timeout
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        box = locator.bounding_box()
        now = time.monotonic()
        if box != last:
            last, since = box, now
        elif now - since >= quiet_s:
            return
        time.sleep(0.03)


def wait_until(
    condition: Callable[[], bool], timeout: float = 10.0, what: str | Callable[[], str] = ""
) -> None:
    """Poll a condition (state read from the server or the page), never a fixed sleep.
    ``what`` may be a function: it is asked at the timeout, to say what was there instead."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.05)
    said = what() if callable(what) else what
    raise AssertionError(f"timed out waiting for {said or condition}")


def camera_is_aimed(view: object) -> bool:
    """Whether the page's last camera report is the top-down camera its world view aimed.

    The page reports its camera back to the server; on a busy machine a report from
    before the aim can arrive after it, and the server's copy is then viser's default
    camera for a while (a projection from it put a robot at pixel row 2405 of 800).
    """
    snap = view.snapshot  # type: ignore[attr-defined]
    assert snap is not None
    aim = (snap.width * geo.MM / 2, snap.height * geo.MM / 2)
    # At least this high: the aim for the widest canvas aimed for (a report with the aim's
    # x and y but an older height was seen under load, the arena cut off at both sides).
    lowest = geo.camera_height(snap.width, snap.height)
    try:
        cam = view.client.camera  # type: ignore[attr-defined]
        x, y, z = cam.position
        return (
            abs(x - aim[0]) < 1e-3
            and abs(y - aim[1]) < 1e-3
            and z >= lowest - 1e-3
            and abs(cam.fov - geo.CAMERA_FOV) < 1e-3
        )
    except AssertionError:  # the page has not reported its camera yet
        return False


def wait_for_aimed_camera(view: object, timeout: float = 30.0) -> None:
    """Wait until the page reports the top-down camera its world view aimed at the arena
    (:func:`camera_is_aimed`)."""
    wait_until(
        lambda: camera_is_aimed(view), timeout, what="the page's camera on the arena, top-down"
    )


# True when the page's canvas itself is at a point (no label, panel or notice over it).
CANVAS_AT_JS = """([x, y]) => {
  const hit = document.elementFromPoint(x, y);
  return hit !== null && hit.tagName === 'CANVAS';
}"""


def screen_points(page, view, world_xy_mm: np.ndarray) -> np.ndarray:
    """World millimetres to page pixels (the top-down camera the view set up; +y is up).

    Through the camera where the view last aimed it, once it has: the server's copy of
    the page's camera report can go stale after the aim (a late report of viser's default
    camera put every robot near pixel (-1600, 2390) while the page's screenshot showed the
    arena aimed; the page reports only when its camera moves, so nothing corrected it).
    """
    box = page.p.locator("canvas").first.bounding_box()
    fitted = view.camera._fitted  # (position, aspect) of the last aim, or None
    cam = view.client.camera
    cx, cy, height = (float(v) for v in (fitted[0] if fitted else cam.position))
    fov = geo.CAMERA_FOV if fitted else cam.fov
    z = geo.ROBOT_Z * 2  # about the top of a robot
    px_per_m = (box["height"] / 2) / ((height - z) * math.tan(fov / 2))
    xy = world_xy_mm * geo.MM
    sx = box["x"] + box["width"] / 2 + (xy[:, 0] - cx) * px_per_m
    sy = box["y"] + box["height"] / 2 - (xy[:, 1] - cy) * px_per_m
    return np.stack([sx, sy], axis=1)


def describe_view(view: Any) -> str:
    """What a world view holds, for a timeout's message (why no frame is drawn)."""
    feed = getattr(view, "feed", None)
    latest = feed.latest() if feed is not None else None
    real = view.snapshot is not None and view.snapshot.real
    return (
        f"a drawn frame: snapshot {'yes' if view.snapshot is not None else 'none'}, "
        f"robots {'made' if view._robots is not None else 'not made'}, "
        f"{view.frames_applied} frames applied (last seq {view.last_seq}), "
        f"feed {'none' if feed is None else 'latest seq ' + str(getattr(latest, 'seq', None))}, "
        f"selected {view.selected!r} of {len(view.robot_names)} robots, "
        f"{'a real arena' if real else 'a simulated world'}"
    )
