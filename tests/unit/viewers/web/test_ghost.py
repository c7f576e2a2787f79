"""The twin's ghost over a live real run: where it is drawn, and when.

The prediction part against the motion model the fit uses (``predict``), then the
page's part with a mocked viser client: drawn a few seconds ahead of the tracked
pose, re-anchored on the next one, the twin asked once per run, hidden by its
checkbox and when the run ends.
"""

from __future__ import annotations

import time
from unittest import mock

import numpy as np
import pytest

from common.lab_errors import LabError
from common.twin.motion import MM_S_PER_UNIT, Drive, ahead, predict
from common.twin.twinfile import Twin
from viewers.web.ghost import DATASHEET, HORIZON_S, Ghost, ghost_path
from viewers.web.prepared_frame import PreparedFrame
from viewers.web.world_feed import RobotReadings, SceneFrame, SceneLayout
from viewers.web.world_view import WorldView

TWIN = Drive(scale_left=0.97, scale_right=1.02, wheel_base_mm=55.0, latency_s=0.0)


@pytest.mark.parametrize("speeds", [(10.0, 10.0), (10.0, 6.0), (-4.0, 5.0)])
def test_the_ghost_is_where_the_fitted_model_puts_the_robot(speeds: tuple[float, float]) -> None:
    start = np.array([400.0, 300.0, 0.7])
    times = np.array([1.0, HORIZON_S])
    got = ahead(TWIN, start, speeds, times)
    commands = np.array([[0.0, speeds[0], speeds[1]]])
    for t, pose in zip(times, got, strict=True):
        want = predict(TWIN, commands, start[None], np.zeros(1), np.array([t]))[0]
        assert pose == pytest.approx(want, abs=0.05)  # mm: predict integrates in 40 steps


def test_a_slipping_wheel_bends_the_ghost_the_datasheet_drives_straight() -> None:
    start = np.array([0.0, 0.0, 0.0])
    datasheet = ghost_path(Drive(), start, np.array([10.0, 10.0]))
    twin = ghost_path(Drive(scale_left=0.95), start, np.array([10.0, 10.0]))
    assert datasheet[-1] == pytest.approx([10 * MM_S_PER_UNIT * HORIZON_S, 0.0, 0.0])
    assert twin[-1][1] > 5.0  # the slower left wheel turns it left, by centimetres in 3 s
    assert twin[0] == pytest.approx(start)  # the path starts at the tracked pose


class RealFeed:
    """A real arena with one robot whose tracked pose the test moves."""

    def __init__(self) -> None:
        self.layout = SceneLayout("arena", 1000.0, 800.0, (), (), (), ("k1",), real=True)
        self.speeds = np.array([10.0, 10.0], np.float32)

    def snapshot(self) -> SceneLayout:
        return self.layout

    def sensors(self, agent: str) -> RobotReadings:
        zeros = np.zeros(8, np.float32)
        return RobotReadings(agent, 0.0, zeros, zeros, self.speeds)


def frame(seq: int, pose: tuple[float, float, float]) -> PreparedFrame:
    poses = np.array([pose], np.float32)
    return PreparedFrame.of(SceneFrame(seq, seq * 0.1, poses, np.zeros(1, np.uint8)))


def settle(ghost: Ghost) -> None:
    """Tick until the twin's answer (asked in a thread) is in and the ghost drawn."""
    for _ in range(200):
        ghost.tick()
        if ghost.drawn_at is not None:
            return
        time.sleep(0.01)
    raise AssertionError("the ghost was never drawn")


def make(twin_of: object, driven: dict[str, bool]) -> tuple[Ghost, WorldView, RealFeed]:
    view = WorldView(mock.MagicMock())
    feed = RealFeed()
    view.feed, view.snapshot, view.selected = feed, feed.layout, 0  # type: ignore[assignment]
    gui = mock.MagicMock()
    gui.add_checkbox.return_value.value = True
    gui.add_markdown.return_value.visible = False
    ghost = Ghost(gui, twin_of, lambda robot: driven.get(robot, False))  # type: ignore[arg-type]
    ghost.bind(view)
    return ghost, view, feed


def test_the_ghost_follows_each_tracked_pose_by_the_twin_asked_once_per_run() -> None:
    twin = mock.MagicMock(spec=Twin)
    twin.drive = TWIN
    twin.model.return_value = "k1's twin fitted 2026-12-05 by carol"
    asked: list[str] = []

    def twin_of(robot: str) -> Twin:
        asked.append(robot)
        return twin

    driven = {"k1": True}
    ghost, view, feed = make(twin_of, driven)
    view.drawn = frame(1, (200.0, 300.0, 0.0))
    settle(ghost)
    speeds = feed.speeds
    assert ghost.drawn_at == pytest.approx(
        ghost_path(TWIN, np.array([200.0, 300.0, 0.0]), speeds)[-1]
    )
    assert ghost.body is not None
    assert ghost.legend.content == "prediction: k1's twin fitted 2026-12-05 by carol"
    # The next tracked pose: the ghost starts again from it (not from where it predicted).
    view.drawn = frame(2, (250.0, 320.0, 1.0))
    ghost.tick()
    assert ghost.drawn_at == pytest.approx(
        ghost_path(TWIN, np.array([250.0, 320.0, 1.0]), speeds)[-1]
    )
    assert asked == ["k1"]  # once for the run, not once a frame
    # Hidden by its checkbox, drawn again when ticked back.
    ghost.checkbox.value = False
    ghost.tick()
    assert ghost.body is None and ghost.drawn_at is None
    ghost.checkbox.value = True
    ghost.tick()
    assert ghost.body is not None
    # The run ends: no ghost; the next run asks for the twin again (a new one may be kept).
    driven["k1"] = False
    ghost.tick()
    assert ghost.body is None
    driven["k1"] = True
    view.drawn = frame(3, (250.0, 320.0, 1.0))
    settle(ghost)
    assert asked == ["k1", "k1"]


def test_a_user_the_registry_shows_no_twins_gets_the_datasheet_said_so() -> None:
    def refused(robot: str) -> Twin:
        raise LabError("you may not read the robots' twins")

    ghost, view, _feed = make(refused, {"k1": True})
    view.drawn = frame(1, (200.0, 300.0, 0.0))
    settle(ghost)
    assert ghost.legend.content.startswith(f"prediction: {DATASHEET} (k1's twin: you may not")
    assert ghost.drawn_at == pytest.approx([200.0 + 10 * MM_S_PER_UNIT * HORIZON_S, 300.0, 0.0])


def test_no_ghost_over_a_simulated_world_nor_a_robot_nobody_runs() -> None:
    ghost, view, _feed = make(lambda robot: None, {})
    view.drawn = frame(1, (200.0, 300.0, 0.0))
    for _ in range(3):
        ghost.tick()
    assert ghost.body is None  # k1 is not driven
    ghost2, view2, _feed2 = make(lambda robot: None, {"k1": True})
    view2.snapshot = SceneLayout("sim", 1000.0, 800.0, (), (), (), ("k1",))
    view2.drawn = frame(1, (200.0, 300.0, 0.0))
    for _ in range(3):
        ghost2.tick()
    assert ghost2.body is None
