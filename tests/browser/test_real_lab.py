"""The page against a REAL lab: router, registry, chat room and engine processes (no fakes).

One lab for the whole module (starting it costs several seconds); each test
opens its own browser contexts and logs in its own users.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common import keys
from common.keys import AliveKind
from tests.browser.conftest import (
    CANVAS_AT_JS,
    describe_view,
    screen_points,
    wait_for_aimed_camera,
    wait_until,
)
from tests.kit.reallab import PASSWORD, WORLD, RealLab, real_lab
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.client import BrowserSession
from viewers.web.live_world import UserWorld
from viewers.web.tabs import tab_label
from viewers.web.world_view import FLOOR_COLOUR

pytestmark = [pytest.mark.integration, pytest.mark.real_lab]

SCENE_BOX = (0, 170, 860, 800)  # left of the docked panel, below viser's WebGL notice


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("reallab"))) as env:
        yield env


def session_of(viewer: WebViewer, user: str) -> BrowserSession:
    for session in list(viewer.sessions.values()):
        if any(t.connection.user == user for t in session.labs.values()):
            return session
    raise AssertionError(f"no browser session for {user}")


def log_in(page, lab: RealLab, user: str, password: str = PASSWORD) -> None:
    page.log_in(lab.url, user, password)
    page.tab(tab_label(lab.address)).first.click()
    page.wait_text("Logged in as")


def online(lab: RealLab) -> set[str]:
    with lab.lab.client("admin") as admin:
        return set(admin.directory().users)


def test_login_wrong_password_and_presence(open_page, lab: RealLab) -> None:
    page = open_page("bob")
    page.log_in(lab.url, "bob", "not-his-password")
    page.wait_text("wrong user name or password")
    page.screenshot("real-wrong-password")
    page.fill("Password", PASSWORD)
    page.click("Log in")
    page.tab(tab_label(lab.address)).first.click()
    page.wait_text("Logged in as")
    page.wait_text("Online:")
    wait_until(lambda: "bob" in online(lab), what="bob online in the registry")
    page.screenshot("real-lobby")
    # Closing the page keeps his session for a reload (the viewer's grace, 1 s here),
    # then logs him out of the registry: his presence goes.
    grace = lab.viewer.parking.grace_s
    lab.viewer.parking.grace_s = 1.0
    try:
        page.p.context.close()
        wait_until(lambda: "bob" not in online(lab), 15, what="bob's presence to go")
    finally:
        lab.viewer.parking.grace_s = grace


def test_two_sessions_chat_through_the_real_room(open_page, lab: RealLab) -> None:
    alice, carol = open_page("alice"), open_page("carol")
    for page, user in ((alice, "alice"), (carol, "carol")):
        log_in(page, lab, user)
        page.join_lobby()
    alice.wait_text("carol joined")
    alice.say("hello carol, over real Zenoh")
    carol.wait_text("hello carol, over real Zenoh")
    carol.say("loud and clear")
    alice.wait_text("loud and clear")
    alice.screenshot("real-chat")
    carol.screenshot("real-chat")


def scene(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB").crop(SCENE_BOX), np.int16)


def test_arena_robots_move_when_driven(open_page, lab: RealLab) -> None:
    page = open_page("ida")
    log_in(page, lab, "ida")
    page.click(f"Join {WORLD}")
    view = session_of(lab.viewer, "ida").view
    wait_until(lambda: view.frames_applied > 5 and view.snapshot is not None, 15, what="frames")
    assert view.snapshot is not None and "k0" in view.snapshot.robots
    feed = view.feed
    assert feed is not None
    start = feed.latest()
    assert start is not None
    start_m = start.poses[0, :2] * geo.MM
    page.draw()  # this test reads the drawn pixels
    with lab.driving("k0"):
        first = scene(page.p.screenshot())
        # Sent to the page: the frame the view drew k0 at has it 40 mm (0.04 m) from its start.
        wait_until(
            lambda: (
                view.drawn is not None and np.hypot(*(view.drawn.positions[0, :2] - start_m)) > 0.04
            ),
            15,
            what="k0 drawn 40 mm from its start",
        )
        # And drawn by it: the page renders what it was sent a little later (software
        # WebGL, 5 frames a second; a screenshot taken at once was the same as before).
        changed = np.zeros((1, 1), bool)

        def scene_changed() -> bool:
            nonlocal changed
            changed = np.abs(first - scene(page.p.screenshot())).sum(axis=2) > 30
            return int(changed.sum()) > 20

        wait_until(scene_changed, 15, what=lambda: f"the page redrawn ({changed.sum()} px changed)")
    page.screenshot("real-arena")
    # The selected robot's plots take real sensor samples.
    view.select(0)
    page.tab(WORLD).last.click()
    page.wait_text("Selected: k0")
    panel = next(iter(session_of(lab.viewer, "ida").labs.values())).panels[WORLD]
    assert panel.robots is not None
    wait_until(lambda: len(panel.robots._t) > 3, 15, what="sensor samples in the plots")
    assert np.asarray(panel.robots._ambient).max() > 0
    page.screenshot("real-plots")


def test_edit_moves_for_the_other_session_and_students_cannot(open_page, lab: RealLab) -> None:
    ida, bob = open_page("ida"), open_page("bob")
    for page, user in ((ida, "ida"), (bob, "bob")):
        log_in(page, lab, user)
        page.click(f"Join {WORLD}")
    ida_session, bob_session = session_of(lab.viewer, "ida"), session_of(lab.viewer, "bob")
    for s in (ida_session, bob_session):
        wait_until(lambda s=s: s.view.snapshot is not None, 15, what="the arena drawn")
    ida_panel = next(iter(ida_session.labs.values())).panels[WORLD]
    bob_panel = next(iter(bob_session.labs.values())).panels[WORLD]
    editor = ida_panel.editor
    assert editor is not None and editor.allowed
    snap = ida_session.view.snapshot
    assert snap is not None
    target = next(o for o in snap.obstacles if not o.ident.startswith("wall"))
    # What a finished gizmo drag does: the gizmo's new pose goes to the engine as an edit.
    editor.select(target.ident)
    assert editor._gizmo is not None
    new_x = target.x + 100.0 if target.x + 200.0 < snap.width else target.x - 100.0
    editor._gizmo.position = (new_x / 1000.0, target.y / 1000.0, 0.04)

    class End:
        phase = "end"

    editor._moved(End())  # type: ignore[arg-type]
    assert not editor.notice.visible, editor.notice.content

    def moved_for_bob() -> bool:
        s = bob_session.view.snapshot
        return s is not None and any(
            o.ident == target.ident and abs(o.x - new_x) < 1.0 for o in s.obstacles
        )

    wait_until(moved_for_bob, 15, what="bob's view to redraw the moved obstacle")
    bob.screenshot("real-edit-seen")

    # bob (student) sees the editor disabled and a plain refusal if he tries.
    bob_editor = bob_panel.editor
    assert bob_editor is not None and not bob_editor.allowed
    assert bob_editor.add_box.disabled
    bob_editor.select(target.ident)
    assert "You may not edit this map" in bob_editor.notice.content
    bob.tab(WORLD).last.click()
    bob.p.get_by_text("Map editor").first.click()
    bob.wait_text("You may not edit this map")
    bob.screenshot("real-editor-refused")
    feed = bob_session.view.feed
    assert isinstance(feed, UserWorld)
    with pytest.raises(Exception, match="edit_map"):
        feed.save_map("nope")


def test_admin_adds_a_user_who_can_then_log_in(open_page, lab: RealLab) -> None:
    admin = open_page("admin")
    log_in(admin, lab, "admin")
    admin.p.get_by_text("Administration").first.click()
    admin.fill("Account", "zoe")
    admin.fill("New password", "zoe-secret-1")
    admin.click("Add account")
    admin.wait_text("user zoe added")
    # The confirmation sits right under the button pressed, in view where the click was made
    # (not at the foot of the form, off-screen on a laptop).
    said = admin.p.get_by_text("user zoe added").first.bounding_box()
    add = admin.p.get_by_role("button", name="Add account").bounding_box()
    set_password = admin.p.get_by_role("button", name="Set password").bounding_box()
    viewport = admin.p.viewport_size
    assert said and add and set_password and viewport
    assert add["y"] < said["y"] < set_password["y"], (add, said, set_password)
    assert said["y"] >= 0 and said["y"] + said["height"] <= viewport["height"], said
    admin.fill("Server name", "")
    admin.click("Rename server")  # another group's answer shows under that group instead
    admin.wait_text("A server name is 1 to")
    assert not admin.p.get_by_text("user zoe added").first.is_visible()
    admin.screenshot("real-admin")
    zoe = open_page("zoe")
    log_in(zoe, lab, "zoe", "zoe-secret-1")
    zoe.screenshot("real-zoe")
    with lab.lab.client("zoe", "zoe-secret-1") as client:
        assert client.user == "zoe"


def test_unknown_lab_and_world_listing(open_page, lab: RealLab) -> None:
    page = open_page("alice")
    page.log_in("wart://alice@10.255.0.1:7447/other", "alice", PASSWORD)
    page.wait_text("does not know the lab")
    # The engine's world is listed in the lobby through its liveliness token.
    assert keys.alive(lab.router.realm, AliveKind.WORLD, WORLD)


# A spot with no robot drawn on it yet: the floor, or the blank canvas before the floor
# (a robot's body renders about 150 from either).
UNDRAWN = (np.array(FLOOR_COLOUR, np.int16), np.array((255, 255, 255), np.int16))


def scene_pixel(page, x: int, y: int) -> np.ndarray:
    from PIL import Image

    png = page.p.screenshot(clip={"x": x, "y": y, "width": 1, "height": 1})
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)[0, 0]


def test_clicking_a_robot_selects_it(open_page, lab: RealLab) -> None:
    """A click on a robot's body selects that robot (viser reports the batched mesh's index).

    Where to click is computed, not looked for in a screenshot: the robot's drawn position
    through the camera the page reports, at a point the DOM says is the canvas itself (not
    under a notice or the panel).
    """
    page = open_page("carol")
    log_in(page, lab, "carol")
    page.click(f"Join {WORLD}")
    view = session_of(lab.viewer, "carol").view
    wait_until(lambda: view.drawn is not None, 30, what=lambda: describe_view(view))
    wait_for_aimed_camera(view)
    target = 0  # no controller runs in this lab: the robots stand still
    spots: list[np.ndarray] = []
    spot: np.ndarray | None = None

    def spot_on_the_robot() -> bool:
        # Projected through the camera where the view aimed it (screen_points), polled until
        # a spot is the canvas itself: a notice or the panel may still cover one.
        nonlocal spots, spot
        drawn, snap = view.drawn, view.snapshot
        if drawn is None or snap is None:
            return False
        ends = screen_points(page, view, np.array([[0.0, 0.0], [snap.robot_radius, 0.0]]))
        radius_px = float(ends[1, 0] - ends[0, 0])
        centre = screen_points(page, view, drawn.positions[[target], :2] / geo.MM)[0]
        # Off the centre: the robot's name label is drawn on it.
        spots = [
            centre + radius_px * np.array(d) for d in ((0, 0.5), (0.5, 0), (-0.5, 0), (0, -0.5))
        ]
        spot = next((s for s in spots if page.p.evaluate(CANVAS_AT_JS, [*map(float, s)])), None)
        return spot is not None

    wait_until(
        spot_on_the_robot,
        30,
        what=lambda: f"a spot on k{target} that is the canvas itself (last tried: {spots})",
    )
    assert spot is not None
    # The page draws what it was sent a little later (software WebGL): a user clicks what
    # they see, so the click waits until something other than floor is drawn at the spot.
    x, y = (int(v) for v in np.rint(spot))
    page.draw()
    wait_until(
        lambda: min(np.abs(scene_pixel(page, x, y) - c).sum() for c in UNDRAWN) > 100,
        15,
        what=lambda: f"k{target} drawn at {x}, {y} (the pixel: {scene_pixel(page, x, y)})",
    )
    page.p.mouse.click(float(spot[0]), float(spot[1]))
    wait_until(lambda: view.selected is not None, 10, what="a robot selected by the click")
    assert view.selected == target, f"clicked k{target}, selected k{view.selected}"
    page.screenshot("real-clicked")


def test_a_student_kicked_from_the_server_is_told_on_the_page(open_page, lab: RealLab) -> None:
    with lab.lab.client("admin") as admin:
        admin.add_user("kim", "kim-secret-1")
        page = open_page("kim")
        log_in(page, lab, "kim", "kim-secret-1")
        wait_until(lambda: "kim" in online(lab), what="kim online")
        admin.kick_from_server("kim", "cheating in the exam")
    page.wait_text("cheating in the exam", timeout=15_000)  # the page says why, at once
    page.screenshot("real-kicked")
    wait_until(lambda: "kim" not in online(lab), 15, what="kim's session to end")


def test_a_shift_click_in_the_arena_adds_a_robot_where_clicked(open_page, lab: RealLab) -> None:
    """A map editor shift-clicks a free spot of the floor: a robot is added there (the world
    takes the free spot nearest the click). Where to click is computed from the camera."""
    page = open_page("ida")
    log_in(page, lab, "ida")
    page.click(f"Join {WORLD}")
    session = session_of(lab.viewer, "ida")
    view = session.view
    wait_until(lambda: view.snapshot is not None, 30, what=lambda: describe_view(view))
    wait_for_aimed_camera(view)
    snap = view.snapshot
    assert snap is not None
    editor = next(iter(session.labs.values())).panels[WORLD].editor
    assert editor is not None and editor.allowed
    wait_until(lambda: editor._click is not None, 15, what="the editor bound to the view")
    wait_until(lambda: view.drawn is not None, 30, what=lambda: describe_view(view))

    def robots() -> dict[str, tuple[float, float]]:
        layout, drawn = view.snapshot, view.drawn
        if layout is None or drawn is None or len(drawn.positions) != len(layout.robots):
            return {}
        xy = drawn.positions[:, :2] / geo.MM
        return {name: (float(xy[i, 0]), float(xy[i, 1])) for i, name in enumerate(layout.robots)}

    taken = [*robots().values(), *((o.x, o.y) for o in snap.obstacles),
             *((b.x, b.y) for b in snap.balls)]  # fmt: skip

    def free(x: float, y: float) -> bool:
        return all(np.hypot(x - px, y - py) > 160.0 for px, py in taken)

    spots = [(x, y) for x in np.linspace(120, snap.width - 120, 15)
             for y in np.linspace(120, snap.height - 120, 15) if free(x, y)]  # fmt: skip
    target, at = None, None
    for x, y in spots:
        point = screen_points(page, view, np.array([[x, y]]))[0]
        if page.p.evaluate(CANVAS_AT_JS, [*map(float, point)]):
            target, at = (x, y), point
            break
    assert target is not None and at is not None, f"no free floor spot in view: {spots}"
    before = set(robots())

    def added() -> list[tuple[str, float, float]]:
        return [(name, x, y) for name, (x, y) in robots().items() if name not in before]

    # The page learns that shift-clicks are wanted from a message of the server's: on a
    # loaded machine a click right after the tab opened can come before it, and is a plain
    # click. A student clicks again; so does this test, until a robot is added.
    for _ in range(4):
        page.p.keyboard.down("Shift")
        page.p.mouse.click(float(at[0]), float(at[1]))
        page.p.keyboard.up("Shift")
        try:
            wait_until(lambda: bool(added()), 8, what="a robot added by the shift-click")
            break
        except AssertionError:
            continue
    wait_until(lambda: bool(added()), 10, what="a robot added by the shift-click")
    _ident, x, y = added()[0]
    assert np.hypot(x - target[0], y - target[1]) < 60.0, ((x, y), target)
    page.p.wait_for_timeout(1500)  # for the picture only: software WebGL draws late
    page.screenshot("real-shift-click-added")
    for name, _x, _y in added():  # the module's lab is shared: the robots go again
        editor.select(name)
        editor._delete()
    wait_until(lambda: not added(), 20, what="the added robots deleted")
