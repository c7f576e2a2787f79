"""Pure parts of the viewer: geometry, text checks, upload checks, the demo lab."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.client.lab_address import LabAddress
from common.messages.agent import MAX_UPLOAD_BYTES
from tests.conftest import REPO
from viewers.web import geometry as geo
from viewers.web.adapters import MAX_CONTROLLER_BYTES, LabError, LoginError
from viewers.web.demo_lab import DemoConnector, DemoLab, DemoWorld
from viewers.web.live_agents import check_upload
from viewers.web.login import check_login_input
from viewers.web.prepared_frame import PreparedFrame
from viewers.web.robot_panel import check_controller, format_agents
from viewers.web.text import check_line, escape_md
from viewers.web.world_feed import MapEdit


def test_poses_to_viser_units_and_heading() -> None:
    poses = np.array([[1000.0, 500.0, math.pi / 2], [0.0, 0.0, 0.0]], np.float32)
    positions, wxyzs = geo.poses_to_viser(poses)
    assert positions[0, :2] == pytest.approx([1.0, 0.5])
    assert positions[:, 2] == pytest.approx([geo.ROBOT_Z] * 2)
    assert geo.wxyz_to_yaw(wxyzs[0]) == pytest.approx(math.pi / 2, abs=1e-6)
    assert wxyzs[1] == pytest.approx([1, 0, 0, 0])


def test_editor_round_trip_is_within_a_millimetre() -> None:
    x, y = geo.viser_to_world(0.3141, 1.2)
    assert (x, y) == pytest.approx((314.1, 1200.0), abs=1e-3)
    for angle in (-3.0, -1.0, 0.0, 0.5, 3.1):
        assert geo.wxyz_to_yaw(geo.yaw_to_wxyz(angle)) == pytest.approx(angle, abs=1e-6)


def test_camera_sees_the_whole_arena() -> None:
    h = geo.camera_height(2000, 2000)
    visible = 2 * h * math.tan(geo.CAMERA_FOV / 2)
    assert 2.0 < visible < 2.5


def test_a_wide_arena_fits_a_narrow_canvas() -> None:
    # 3 m by 1 m in the 820x800 canvas a 1280x800 screen leaves beside the panel.
    aspect = 820 / 800
    h = geo.camera_height(3000, 1000, aspect)
    visible_w = 2 * h * math.tan(geo.CAMERA_FOV / 2) * aspect
    assert 3.0 < visible_w < 3.5


def test_a_click_ray_finds_the_robot_it_lands_on() -> None:
    radius = 27.5 * geo.MM
    positions = np.array([[1.0, 1.0, geo.ROBOT_Z], [1.2, 1.0, geo.ROBOT_Z]], np.float32)
    down = (0.0, 0.0, -1.0)
    assert geo.robot_at((1.01, 1.0, 3.0), down, positions, radius) == 0
    assert geo.robot_at((1.19, 1.02, 3.0), down, positions, radius) == 1
    # A slanted ray from a camera off to the side lands where it meets the plane.
    origin = (0.0, 1.0, 2.0 + geo.ROBOT_Z)
    assert geo.robot_at(origin, (0.6, 0.0, -1.0), positions, radius) == 1
    assert geo.robot_at((1.1, 1.0, 3.0), down, positions, radius) is None  # between them
    assert geo.robot_at((1.0, 1.0, 3.0), (1.0, 0.0, 0.0), positions, radius) is None
    assert geo.robot_at((1.0, 1.0, 3.0), (0.0, 0.0, 1.0), positions, radius) is None
    assert geo.robot_at((1.0, 1.0, 3.0), down, positions[:0], radius) is None


def test_robot_mesh_and_rays() -> None:
    vertices, faces = geo.robot_mesh(0.0275)
    assert faces.max() < len(vertices) and len(faces) == 3 * 16 + 1
    rays = geo.ir_segments([100, 100, 0], np.full(8, 1023.0), 27.5)
    assert rays.shape == (8, 2, 3)
    lengths = np.linalg.norm(rays[:, 1] - rays[:, 0], axis=1)
    assert lengths == pytest.approx([geo.IR_RAY_MM * geo.MM] * 8, abs=1e-6)  # touching: longest
    nothing = geo.ir_segments([100, 100, 0], np.zeros(8), 27.5)
    assert np.linalg.norm(nothing[:, 1] - nothing[:, 0], axis=1) == pytest.approx(
        [geo.IR_STUB_MM * geo.MM] * 8,
        abs=1e-6,  # a stub shows where each sensor looks
    )
    # Rays start at the body's rim, on the sensor's bearing (sensor 2: 10 degrees left).
    start = rays[2, 0, :2] / geo.MM
    assert math.degrees(math.atan2(start[1] - 100, start[0] - 100)) == pytest.approx(10, abs=1e-3)
    assert geo.trail_segments(np.zeros((1, 2), np.float32)).shape == (0, 2, 3)


def test_prepared_frame_colours_by_gripper() -> None:
    world = DemoWorld(robots=5, start=False)
    prepared = PreparedFrame.of(world.produce(1.0))
    assert prepared.positions.shape == (5, 3) and prepared.colours.shape == (5, 3)


def test_text_is_escaped_and_checked() -> None:
    shown = escape_md("<img src=x> [link](http://e) **bold**")
    assert "<" not in shown and "\\[" in shown and "\\*" in shown
    assert check_line("   ")
    assert check_line("x" * 1001)
    assert check_line("two\nlines")
    assert check_line("fine") is None
    assert check_login_input("", "pw") == "Type your user name."
    assert check_login_input("a b", "pw")
    assert check_login_input("ana", "")
    assert check_login_input("ana", "pw") is None


def test_controller_uploads_are_checked_not_run() -> None:
    good = b"from common.controller import Controller\n\nclass C(Controller):\n    pass\n"
    assert check_controller("ctl.py", good) is None
    assert "not a Python file" in (check_controller("ctl.exe", good) or "")
    assert "empty" in (check_controller("ctl.py", b"") or "")
    # The page's limit is the agent context's (one constant): 64 KiB.
    assert MAX_CONTROLLER_BYTES == MAX_UPLOAD_BYTES == 64 * 1024
    too_big = check_controller("ctl.py", good + b"#" * MAX_CONTROLLER_BYTES) or ""
    assert "limited to 64 KiB" in too_big
    assert "UTF-8" in (check_controller("ctl.py", b"\xff\xfe") or "")
    assert "line 1" in (check_controller("ctl.py", b"def (:") or "")
    assert "defines no controller" in (check_controller("ctl.py", b"x = 1\n") or "")
    boom = b"raise SystemExit('ran!')\nclass B(Controller):\n    pass\n"
    assert check_controller("boom.py", boom) is None  # parsed, never executed
    assert "../" not in (check_controller("../../x.txt", good) or "")
    assert check_upload("C:\\Users\\me\\ctl.py", good) == ("ctl.py", None)
    example = (REPO / "examples" / "01_braitenberg.py").read_bytes()
    assert check_controller("01_braitenberg.py", example) is None


def test_fake_lab_behaves_like_a_lab() -> None:
    lab = DemoLab(robots=4)
    try:
        connector = DemoConnector(("lab", lab))
        where = LabAddress("127.0.0.1")
        with pytest.raises(LoginError, match="wrong user name or password"):
            connector.login(where, "ana", "nope")
        with pytest.raises(LoginError, match="no lab answers"):
            connector.login(LabAddress("127.0.0.1", realm="other"), "ana", "ana-pw")
        ana = connector.login(where, "ana", "ana-pw")
        ben = connector.login(where, "ben", "ben-pw")
        seen: list[object] = []
        ben.subscribe(seen.append)
        ben.join("lobby")
        ana.join("lobby")
        ana.say("lobby", "hi")
        assert any(getattr(e, "line", None) and e.line.text == "hi" for e in seen)
        with pytest.raises(LabError, match="no 'host' permission"):
            ben.host("chat", "mine")
        assert ana.host("agent", "arena2") == "arena2"
        with pytest.raises(LabError, match="may not kick"):
            ben.kick("lobby", "ana")
        ana.kick("lobby", "ben")
        assert "ben" not in [
            m
            for c in ana.directory().contexts
            if c.ctx == "lobby"
            for m in ("ben",)
            if c.members > 1
        ]
        world = ana.world("arena")
        world.edit(MapEdit("move", "obstacle", "box1", x=10, y=20, angle=0.5))
        moved = next(o for o in world.snapshot().obstacles if o.ident == "box1")
        assert (moved.x, moved.y, moved.angle) == (10, 20, 0.5)
        assert world.snapshot().version == 1
        queued = ben.request_control("arena", "k0", "c.py", b"pass")
        assert queued.position == 0  # nobody else: it runs now
        with pytest.raises(LabError, match="already have a request"):
            ben.request_control("arena", "k0", "c.py", b"pass")
        assert format_agents(ben.agents("arena")).count("| k") == 4
        with pytest.raises(LabError, match="only the owner"):
            ben.set_slot("arena", 5)
        assert ana.arena_settings("arena").can_manage
        assert not ben.arena_settings("arena").can_manage
        ana.set_slot("arena", 5)
        assert "Slots of 5 s" in format_agents(ben.agents("arena"), ben.arena_settings("arena"))
        assert "cancelled" in ben.cancel_control("arena", "k0")
        with pytest.raises(LabError, match="no request"):
            ben.cancel_control("arena", "k0")
        ana.logout()
        assert "ana" not in ben.directory().users
    finally:
        lab.close()


def test_an_ir_ray_grows_with_its_reading_and_reddens() -> None:
    """The issue's words: "IR readings drawn as rays that grow with the reading"."""
    readings = np.array([0, 100, 200, 400, 600, 800, 1000, 1023], np.float32)
    rays = geo.ir_segments([500, 500, 0.3], readings, 27.5)
    lengths = np.linalg.norm(rays[:, 1] - rays[:, 0], axis=1) / geo.MM
    assert np.all(np.diff(lengths) > 0)  # every step up in reading, a longer ray
    # Proportional above the stub: twice the reading, twice the length.
    assert lengths[3] == pytest.approx(2 * lengths[2], rel=1e-4)
    assert lengths[7] == pytest.approx(geo.IR_RAY_MM, rel=1e-4)
    colours = geo.ir_colours(readings)
    assert colours.shape == (8, 2, 3) and colours.dtype == np.uint8
    assert (colours[:, 0] == colours[:, 1]).all()  # one colour per ray
    assert np.all(np.diff(colours[:, 0, 1].astype(int)) <= 0)  # less green as it rises
    assert tuple(colours[7, 0]) == tuple(geo.IR_HIGH_RGB.astype(np.uint8))
    assert tuple(colours[0, 0]) == tuple(geo.IR_LOW_RGB.astype(np.uint8))
    # Out-of-range readings are clipped, never drawn past the top of the scale.
    over = geo.ir_segments([0, 0, 0], np.full(8, 5000.0), 27.5)
    assert np.linalg.norm(over[:, 1] - over[:, 0], axis=1).max() / geo.MM == pytest.approx(
        geo.IR_RAY_MM, rel=1e-4
    )


def test_the_follow_camera_shifts_sideways_and_keeps_height_and_look() -> None:
    position, look_at = (1.0, 1.0, 6.0), (1.0, 1.0, 0.0)  # top-down over the arena's centre
    moved = geo.follow_camera(position, look_at, (0.3, 1.7))
    assert moved is not None
    new_pos, new_look = moved
    assert new_look == pytest.approx((0.3, 1.7, 0.0))
    assert new_pos == pytest.approx((0.3, 1.7, 6.0))  # same height, still straight down
    # A student who zoomed in and tilted keeps both: the offset is kept, shifted.
    tilted = geo.follow_camera((1.2, 0.8, 2.0), (1.0, 1.0, 0.0), (0.5, 0.5))
    assert tilted is not None
    assert tilted[0] == pytest.approx((0.7, 0.3, 2.0)) and tilted[1] == pytest.approx((0.5, 0.5, 0))
    # Within the dead band (2 mm) the camera is left alone: no message for a still robot.
    assert geo.follow_camera(new_pos, new_look, (0.3005, 1.7005)) is None
    assert geo.follow_camera(new_pos, new_look, (float("nan"), 1.0)) is None


def test_the_plots_draw_each_thing_in_the_views_colour() -> None:
    from common.recording import plots
    from viewers.web import world_view

    def hexed(rgb: object) -> str:
        return "#" + "".join(f"{int(c):02x}" for c in rgb)  # type: ignore[attr-defined]

    assert hexed(world_view.BALL_COLOUR) == plots.BALL_COLOUR
    assert hexed(world_view.OBSTACLE_COLOUR) == plots.OBSTACLE_COLOUR
    assert hexed(world_view.GRIPPER_COLOURS[0]) == plots.ROBOT_COLOUR
