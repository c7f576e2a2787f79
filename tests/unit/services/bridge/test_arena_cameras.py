"""The bridge's cameras: offline when the process goes, not when a busy host's frames stall."""

from __future__ import annotations

from common.tracking.fusion import PoseFusion
from services.bridge.cameras import CAMERA_HUNG_S, ArenaCameras


def fusion_with_k1() -> PoseFusion:
    fusion = PoseFusion(1000, 1000, camera_silent_after_s=CAMERA_HUNG_S)
    fusion.odometry("k1", 300, 300, 0, at=0.0)
    return fusion


def test_a_slow_camera_keeps_an_unseen_robot_where_it_was_last_trusted() -> None:
    fusion = fusion_with_k1()
    cameras = ArenaCameras(fusion)
    cameras.presence("cam", True)
    assert cameras.frame("cam", captured_at=0.0, now=0.0) == 0.0
    fusion.seen("k1", 300, 300, 0, captured_at=0.0)
    tracked = fusion.pose("k1", 0.1)
    assert tracked is not None and tracked.source == "tracked"
    # The camera's next frame comes 4 s later (its host is busy); the robot drove off meanwhile.
    fusion.odometry("k1", 700, 300, 0, at=4.0)
    shown = fusion.pose("k1", 4.0)
    assert shown is not None and shown.source == "not seen"
    assert (shown.x, shown.y) == (300, 300)


def test_a_camera_whose_process_is_gone_is_offline_at_once_and_its_late_frames_ignored() -> None:
    fusion = fusion_with_k1()
    cameras = ArenaCameras(fusion)
    cameras.presence("cam", True)
    cameras.frame("cam", captured_at=0.0, now=0.0)
    cameras.presence("cam", False)
    shown = fusion.pose("k1", 0.1)
    assert shown is not None and shown.source == "odometry"
    assert cameras.frame("cam", captured_at=0.05, now=0.2) is None  # still on its way
    assert not fusion.camera_live(0.2)
    # Another camera's process leaving says nothing about ours.
    cameras.presence("cam", True)
    cameras.frame("cam", captured_at=0.3, now=0.3)
    cameras.presence("elsewhere", False)
    assert fusion.camera_live(0.4)


def test_a_hung_camera_goes_offline_after_its_silence() -> None:
    fusion = fusion_with_k1()
    cameras = ArenaCameras(fusion)
    cameras.presence("cam", True)
    cameras.frame("cam", captured_at=0.0, now=0.0)
    assert fusion.camera_live(CAMERA_HUNG_S - 0.1)
    assert not fusion.camera_live(CAMERA_HUNG_S + 0.1)


def test_many_camera_names_do_not_grow_the_bridge() -> None:
    cameras = ArenaCameras(fusion_with_k1())
    for i in range(1000):
        cameras.frame(f"c{i}", captured_at=0.0, now=0.0)
        cameras.presence(f"x{i}", False)
    assert len(cameras._clocks) <= 16 and len(cameras._left) <= 16


def test_one_of_two_cameras_gone_keeps_the_arena_tracked_by_the_other() -> None:
    fusion = fusion_with_k1()
    cameras = ArenaCameras(fusion)
    for camera in ("left", "right"):
        cameras.presence(camera, True)
        cameras.frame(camera, captured_at=0.0, now=0.0)
    fusion.seen("k1", 300, 300, 0, captured_at=0.0, camera="left")
    cameras.presence("left", False)
    assert fusion.camera_live(0.1)  # the right one lives: the arena has a camera
    shown = fusion.pose("k1", 0.1)
    assert shown is not None and shown.source == "odometry"  # k1's own camera is gone
    cameras.presence("right", False)
    assert not fusion.camera_live(0.1)
