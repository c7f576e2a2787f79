"""Pure parts of the viewer: geometry, text checks, upload checks, the demo lab."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.messages.agent import MAX_UPLOAD_BYTES
from tests.conftest import REPO
from viewers.web import geometry as geo
from viewers.web.adapters import MAX_CONTROLLER_BYTES, LabError, LoginError, MapEdit
from viewers.web.address import LabAddress
from viewers.web.demo_lab import DemoConnector, DemoLab, DemoWorld
from viewers.web.login import check_login_input
from viewers.web.real_agents import check_upload
from viewers.web.robot_panel import check_controller, format_agents
from viewers.web.text import check_line, escape_md
from viewers.web.world_view import PreparedFrame


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


def test_robot_mesh_and_rays() -> None:
    vertices, faces = geo.robot_mesh(0.0275)
    assert faces.max() < len(vertices) and len(faces) == 3 * 16 + 1
    rays = geo.ir_segments([100, 100, 0], np.full(8, 1023.0), 27.5)
    assert rays.shape == (8, 2, 3)
    lengths = np.linalg.norm(rays[:, 1] - rays[:, 0], axis=1)
    assert lengths == pytest.approx(0.0, abs=1e-6)  # touching: zero-length rays
    far = geo.ir_segments([100, 100, 0], np.zeros(8), 27.5)
    assert np.linalg.norm(far[:, 1] - far[:, 0], axis=1) == pytest.approx(
        [geo.IR_RANGE_MM * geo.MM] * 8, abs=1e-6
    )
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
