"""A robot or an object removed from the world (by this page's editor or anyone's) while the
view shows it: the view redraws without a traceback and keeps the selection by name.

The viser client is a mock; the frames come from a stand-in feed, through the frame pump
(which logs any exception a view raises: caplog sees it).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from unittest import mock

import numpy as np
import pytest

from viewers.web.pump import FramePump
from viewers.web.world_feed import Ball, SceneFrame, SceneLayout
from viewers.web.world_view import WorldView

ROBOTS = ("k0", "k1", "k2", "k3", "s1")  # s1: a robot of a type a student built


class Feed:
    """A world's snapshot and newest frame, changed by the test as edits would."""

    def __init__(self, robots: tuple[str, ...]) -> None:
        self.layout = SceneLayout(
            "w1", 1000.0, 1000.0, (), (Ball("ball1", 500.0, 500.0, 20.0),), (), robots
        )
        self.seq = 0

    def snapshot(self) -> SceneLayout:
        return self.layout

    def latest(self) -> SceneFrame:
        self.seq += 1
        n = len(self.layout.robots)
        poses = np.array([[100.0 + 150 * i, 200.0, 0.0] for i in range(n)], np.float32)
        poses = poses.reshape(n, 3)  # (0, 3) once the last robot is gone, as the engine's
        balls = np.array([[b.x, b.y] for b in self.layout.balls], np.float32).reshape(-1, 2)
        return SceneFrame(self.seq, 0.1 * self.seq, poses, np.zeros(n, np.uint8), ball_xy=balls)

    def sensors(self, agent: str) -> None:
        return None

    def remove(self, ident: str) -> None:
        snap = self.layout
        self.layout = replace(
            snap,
            robots=tuple(r for r in snap.robots if r != ident),
            balls=tuple(b for b in snap.balls if b.ident != ident),
            version=snap.version + 1,
        )


@pytest.fixture
def watched() -> tuple[FramePump, WorldView, Feed, list[int | None]]:
    feed = Feed(ROBOTS)
    view = WorldView(mock.MagicMock())
    view.show(feed)  # type: ignore[arg-type]
    told: list[int | None] = []
    view.on_select.append(told.append)
    pump = FramePump()
    pump.attach(view)
    pump.tick()
    return pump, view, feed, told


def test_removing_the_selected_last_robot_logs_nothing(
    watched: tuple[FramePump, WorldView, Feed, list[int | None]], caplog: pytest.LogCaptureFixture
) -> None:
    pump, view, feed, told = watched
    view.select(4)  # the custom robot, the last of the frame's rows
    with caplog.at_level(logging.DEBUG):
        feed.remove("s1")
        pump.tick()
        pump.tick()
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING], caplog.text
    assert view.selected is None and view.selected_name is None
    assert told == [4, None]  # the editor is told: its handles on s1 go
    assert view.frames_applied == 3


def test_removing_a_robot_before_the_selected_one_keeps_the_selection(
    watched: tuple[FramePump, WorldView, Feed, list[int | None]], caplog: pytest.LogCaptureFixture
) -> None:
    pump, view, feed, told = watched
    view.select(3)
    feed.remove("k1")
    pump.tick()
    assert not caplog.records, caplog.text
    assert view.selected_name == "k3" and view.selected == 2
    assert told == [3, 2]


def test_removing_every_robot_and_an_object_logs_nothing(
    watched: tuple[FramePump, WorldView, Feed, list[int | None]], caplog: pytest.LogCaptureFixture
) -> None:
    pump, view, feed, _ = watched
    view.select(0)
    for ident in ("ball1", *ROBOTS):
        feed.remove(ident)
        pump.tick()
    assert not caplog.records, caplog.text
    assert view.robot_names == () and view.selected is None


def test_showing_the_world_shown_already_keeps_the_selection_and_its_trail(
    watched: tuple[FramePump, WorldView, Feed, list[int | None]],
) -> None:
    """The page says again which tab is in front (a late event on a busy machine): the
    robot the student selected stays selected, its trail drawn; another world drops it."""
    pump, view, feed, told = watched
    view.select(1)
    for _ in range(10):
        pump.tick()
    trail = view._trail_handle
    assert trail is not None
    view.show(feed)  # type: ignore[arg-type]
    pump.tick()
    assert (view.selected, view._trail_handle, told) == (1, trail, [1])
    view.show(Feed(ROBOTS))  # type: ignore[arg-type]
    assert (view.selected, view._trail_handle) == (None, None)
