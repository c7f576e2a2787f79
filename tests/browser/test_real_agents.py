"""The robot panel against a REAL agent context, runner and engine (no fakes).

One lab for the module: router, registry, engine (with a service identity:
MAC leases), runner (bubblewrap sandboxes) and the agent context ``arena``
(owner ida, 30 s slots: longer than an upload takes on a busy machine, so which
request waits behind which never depends on the machine's speed; students end
their runs themselves). Students upload controllers from the page, see their
place in the queue, the robot obey, the output, and the queue advance.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout

from tests.browser.conftest import (
    CANVAS_AT_JS,
    ViserPage,
    screen_points,
    wait_for_aimed_camera,
    wait_until,
)
from tests.browser.test_real_lab import session_of
from tests.conftest import REPO, needs_sandbox
from tests.kit.reallab import CTX, PASSWORD, WORLD, RealLab, real_lab
from viewers.web.chat_panel import ChatPanel
from viewers.web.tabs import tab_label

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

SLOT = 30.0
BRAITENBERG = REPO / "examples" / "01_braitenberg.py"
HELLO = b'''"""Says hello, then spins on the spot."""

from common.controller import Controller, Khepera


class Hello(Controller):
    period = 0.1

    def initialize(self, robot: Khepera) -> None:
        print("hello from a sandbox")

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(-5, 5)
'''


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("agentlab")), agents=True, slot=SLOT) as env:
        yield env


def enter_arena(page: ViserPage, lab: RealLab, user: str) -> ChatPanel:
    """Log in, join the agent context from the lobby, open its tab; its server-side panel."""
    page.log_in(lab.url, user, PASSWORD)
    page.tab(tab_label(lab.address)).first.click()
    page.wait_text("Logged in as")
    page.click(f"Join {CTX}", timeout=15_000)
    page.tab(f"{CTX} (arena)").last.click()
    page.wait_text("Upload controller")
    session = session_of(lab.viewer, user)
    # The tab shows while its panel is still being built (the editor comes after the robots).
    panels = next(iter(session.labs.values())).panels
    wait_until(lambda: CTX in panels, 10, what=f"{user}'s {CTX} panel")
    return panels[CTX]


def choose(page: ViserPage, label: str, option: str) -> None:
    page.input_after_label(label).click()
    page.p.get_by_role("option", name=option, exact=True).click()


def pick_robot(page: ViserPage, panel: ChatPanel, agent: str) -> None:
    """Choose a robot in the panel's list; wait until the server has the choice."""
    choose(page, "Robot", agent)
    robots = panel.robots
    assert robots is not None
    wait_until(lambda: robots.robot.value == agent, 10, what=f"{agent} chosen")


def upload(page: ViserPage, name: str, content: bytes) -> None:
    page.p.locator("input[type=file]").last.set_input_files(
        {"name": name, "mimeType": "text/x-python", "buffer": content}
    )


def said_to(panel: ChatPanel, lab: RealLab) -> str:
    """What the server put in a panel's output, and what the runner logged: a timeout's cause."""
    robots = panel.robots
    shown = list(robots._output)[-4:] if robots is not None else []
    runner = next((p for p in lab.lab.procs.started if p.name == "runner"), None)
    logged = runner.output().splitlines()[-8:] if runner is not None else []
    return f"the panel holds {shown}; the runner's log ends {logged}"


def test_upload_queue_obey_output_and_advance(open_page, lab: RealLab) -> None:
    alice, bob = open_page("alice"), open_page("bob")
    alice_panel = enter_arena(alice, lab, "alice")
    bob_panel = enter_arena(bob, lab, "bob")
    # Joining the agent context shows its world in the 3D view (the first arena joined).
    view = session_of(lab.viewer, "alice").view
    wait_until(lambda: view.frames_applied > 3, 15, what="the arena's frames in alice's view")
    assert view.feed is not None and view.feed.world == WORLD
    assert "k0" in view.robot_names
    assert alice_panel.robots is not None and bob_panel.robots is not None
    assert not alice_panel.robots.manage.visible  # a student: no instructor controls

    # A file that cannot run is refused in the page, in words, before anything queues.
    pick_robot(alice, alice_panel, "k0")
    upload(alice, "broken.py", b"from common.controller import Controller\ndef (:\n")
    alice.wait_text("Not queued: broken.py, line 2: syntax error")

    pick_robot(bob, bob_panel, "k0")
    start = view.feed.latest()
    assert start is not None
    upload(alice, BRAITENBERG.name, BRAITENBERG.read_bytes())
    alice.wait_text("01_braitenberg.py is queued for k0")
    # bob queues behind her: his place and the ETA show on his page.
    upload(bob, "hello.py", HELLO)
    bob.wait_text("you are #1 in the queue")
    bob.p.get_by_role("cell", name="#1", exact=True).first.wait_for(timeout=10_000)  # "me"
    bob.screenshot("agents-queued")

    # The robot obeys alice's controller: k0 moves in the frames.
    def k0_moved() -> bool:
        frame = view.feed.latest() if view.feed else None
        return frame is not None and bool(np.hypot(*(frame.poses[0, :2] - start.poses[0, :2])) > 30)

    wait_until(k0_moved, 15, what="k0 driven by the uploaded Braitenberg controller")
    alice.screenshot("agents-running")

    # The queue advances: she ends her run, bob's controller runs and prints.
    alice.click("Cancel my request")
    alice.wait_text("your controller on k0 was cancelled: cancelled by alice", timeout=15_000)
    alice.wait_text("bob's controller on k0 is running", timeout=15_000)
    try:
        bob.wait_text("hello from a sandbox", timeout=15_000)
    except PlaywrightTimeout:
        raise AssertionError(f"bob's print not on his page: {said_to(bob_panel, lab)}") from None
    bob.screenshot("agents-output")
    alice.wait_text("hello from a sandbox", timeout=10_000)  # members see the output too
    bob.click("Cancel my request")
    bob.wait_text("your controller on k0 was cancelled: cancelled by bob", timeout=15_000)
    alice.screenshot("agents-advanced")


def test_cancel_and_owner_controls(open_page, lab: RealLab) -> None:
    ida, carol, alice = open_page("ida"), open_page("carol"), open_page("alice")
    ida_panel = enter_arena(ida, lab, "ida")
    carol_panel = enter_arena(carol, lab, "carol")
    alice_panel = enter_arena(alice, lab, "alice")
    assert ida_panel.robots is not None and alice_panel.robots is not None
    wait_until(lambda: ida_panel.robots.manage.visible, 10, what="ida's arena settings")
    assert not alice_panel.robots.manage.visible

    # The owner lengthens the slots from the page: long enough that carol's slot cannot run
    # out on a loaded machine before ida stops it below (the stop is what ends it).
    ida.p.get_by_text("Arena settings").first.click()
    ida.fill("Slot length (s)", "300")
    ida.click("Set slot length")
    ida.wait_text("slots of 300 s from the next one")

    pick_robot(carol, carol_panel, "k1")
    upload(carol, BRAITENBERG.name, BRAITENBERG.read_bytes())
    carol.wait_text("01_braitenberg.py is queued for k1")
    pick_robot(alice, alice_panel, "k1")
    upload(alice, "hello.py", HELLO)
    alice.wait_text("you are #1 in the queue")
    alice.screenshot("agents-before-cancel")
    # Cancel from the page: alice leaves the queue.
    alice.click("Cancel my request")
    alice.wait_text("cancelled")
    wait_until(
        lambda: not any(r.agent == "k1" and r.my_request for r in alice_panel.robots._rows),
        10,
        what="alice's request gone from her table",
    )

    # The owner stops carol's running controller, then turns remote control off and on.
    pick_robot(ida, ida_panel, "k1")
    ida.click("Stop the running controller")
    ida.wait_text("stopping carol's controller on k1")  # the context's answer, in names
    carol.wait_text("your controller on k1 was cancelled: stopped by ida", timeout=15_000)
    ida.click("Disable remote control")
    ida.wait_text("remote control is off")
    upload(alice, "hello.py", HELLO)
    alice.wait_text("is disabled")
    ida.screenshot("agents-owner-controls")
    ida.click("Enable remote control")
    ida.wait_text("remote control on for every agent")
    ida.fill("Slot length (s)", str(int(SLOT)))
    ida.click("Set slot length")
    ida.wait_text(f"slots of {SLOT:g} s from the next one")


def _rgb(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


def test_mouse_drag_of_the_gizmo_moves_an_obstacle_for_the_other_session(
    open_page, lab: RealLab
) -> None:
    """A real drag: mouse down on the gizmo's x arrow, move, up; bob's view redraws it."""
    ida, bob = open_page("ida"), open_page("bob")
    ida_panel = enter_arena(ida, lab, "ida")
    enter_arena(bob, lab, "bob")
    ida_view, bob_view = session_of(lab.viewer, "ida").view, session_of(lab.viewer, "bob").view
    wait_until(lambda: ida_view.frames_applied > 3, 15, what="ida's arena drawn")
    snap = ida_view.snapshot
    assert snap is not None and ida_panel.editor is not None
    target = next(o for o in snap.obstacles if not o.ident.startswith("wall"))
    wait_for_aimed_camera(ida_view)
    ida.draw()  # the grab is found on the drawn gizmo's pixels
    ida_panel.editor.select(target.ident)  # what clicking it does (tested in test_real_lab)
    # Where the gizmo's x arrow is, by geometry: from the box's centre along its heading,
    # as long as the gizmo's scale (0.25 m). The drag grabs the first point of it that the
    # page has drawn red (software WebGL draws the gizmo a little after it is sent).
    heading = np.array([math.cos(target.angle), math.sin(target.angle)])
    along = np.array([target.x, target.y]) + np.outer(np.linspace(0.3, 0.9, 13) * 250.0, heading)
    grab: list[tuple[float, float]] = []

    def arrow_drawn() -> bool:
        points = screen_points(ida, ida_view, along)
        image = _rgb(ida.p.screenshot())
        for px, py in points:
            ix, iy = int(np.rint(px)), int(np.rint(py))
            if not (0 <= iy < image.shape[0] and 0 <= ix < image.shape[1]):
                continue
            r, g, b = image[iy, ix]
            if r > 150 and g < 110 and b < 110 and ida.p.evaluate(CANVAS_AT_JS, [px, py]):
                grab[:] = [(float(px), float(py))]
                return True
        return False

    wait_until(arrow_drawn, 15, what=f"the gizmo's red x arrow drawn along {along.tolist()}")
    x, y = grab[0]
    mouse = ida.p.mouse
    mouse.move(x, y)
    mouse.down()
    for step in range(1, 11):
        mouse.move(x + 8 * step, y, steps=2)
    mouse.up()
    ida.screenshot("gizmo-dragged")

    def moved_for_bob() -> bool:
        s = bob_view.snapshot
        moved = next((o for o in s.obstacles if o.ident == target.ident), None) if s else None
        # The gizmo turns with the box: its x arrow points along the box's heading, so
        # a drag to the right moves the box along that arrow (right, and up or down).
        return moved is not None and moved.x - target.x > 20

    wait_until(moved_for_bob, 15, what="bob's view to show the obstacle dragged to the right")
    bob.screenshot("gizmo-drag-seen")
