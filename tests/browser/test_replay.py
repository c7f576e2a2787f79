"""A recorded run replayed in Chromium: listed in the arena's Recordings, summarised, and
replayed in the world view, the robot drawn where the recording says as the cursor moves.

Against the demo lab (a synthetic recording offered to ben); the real lab's own
recording of a slot is tested in test_real_recordings.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from common.recording import read_recording
from tests.browser.conftest import ViserPage, join_demo_arena, wait_until
from tests.unit.common.test_recording import _record
from viewers.web import geometry as geo
from viewers.web.app import WebViewer
from viewers.web.chat_panel import ChatPanel
from viewers.web.client import BrowserSession
from viewers.web.demo_lab import DemoLab
from viewers.web.recordings_panel import RecordingsPanel
from viewers.web.replay import ReplayControls, ReplayFeed
from viewers.web.world_view import WorldView


def drawn_xy_mm(view: WorldView, agent: str) -> np.ndarray:
    """Where the view last drew ``agent`` (server-side: what its mesh was given), in mm."""
    positions = view.drawn_positions()
    assert positions is not None
    return positions[view.robot_names.index(agent), :2] / geo.MM


def open_recordings(page: ViserPage, session: BrowserSession) -> tuple[ChatPanel, RecordingsPanel]:
    page.tab("arena (arena)").last.click()
    page.wait_text("Upload controller")
    tab = next(iter(session.labs.values()))
    wait_until(lambda: "arena" in tab.panels, what="ben's arena panel")
    panel = tab.panels["arena"]
    assert panel.recordings is not None
    page.p.get_by_text("Recordings", exact=True).first.click()  # the folder opens
    page.click("Refresh")
    return panel, panel.recordings


def test_a_recording_replayed_in_the_page_moves_the_robot_with_the_cursor(
    open_page, viewer: WebViewer, fake_lab: DemoLab, tmp_path: Path
) -> None:
    path = tmp_path / "k1-1-abc.mcap"
    _record(path, seconds=3.0, user="ben")
    fake_lab.add_recording("arena", path)
    rec = read_recording(path)
    assert rec.info is not None
    agent = rec.info.agent

    page, session = join_demo_arena(open_page, viewer, "ben")
    view = session.view
    wait_until(lambda: view.frames_applied > 3, what="the live arena in ben's view")
    live = view.feed

    panel, recordings = open_recordings(page, session)
    page.wait_text("1 recording.")
    assert recordings.chosen.value.startswith(agent)
    page.wait_text("finished: the controller raised")  # the table says how it ended
    page.click("Summary")
    page.wait_text("distance:")
    assert "ZeroDivisionError" in recordings.details.content

    page.click("Plots")  # matplotlib's two PNGs, shown as images in the folder
    page.wait_text("Plots of k1-1-abc: below.", timeout=30_000)
    assert len(recordings._images) == 2
    # Each plot is as wide as the panel lets it be (its box's width), not a fixed small size.
    widths = page.p.evaluate(
        "() => [...document.querySelectorAll('img')]"
        ".filter(i => i.naturalWidth > 400 && i.clientWidth > 0)"
        ".map(i => [i.clientWidth, i.parentElement.clientWidth])"
    )
    assert len(widths) == 2 and all(w >= box - 1 for w, box in widths), widths

    page.click("Replay")
    wait_until(lambda: recordings.replay is not None, what="the replay controls")
    controls = recordings.replay
    assert isinstance(controls, ReplayControls)
    assert isinstance(view.feed, ReplayFeed) and view.feed is controls.feed
    assert panel.robots is not None and panel.robots.feed is controls.feed  # panels follow
    timeline = controls.player.timeline
    page.wait_text("Back to live")

    def pose_at(t: float) -> np.ndarray:
        frame = timeline.at(t).frame
        i = frame.rows.index(agent)
        return np.array([frame.x[i], frame.y[i]])

    # The student scrubs with the slider (keyboard on its thumb): Home, then End.
    thumb = page.p.get_by_role("slider").last
    thumb.focus()
    thumb.press("Home")
    wait_until(lambda: controls.player.cursor == 0.0, what="the cursor at the start")
    wait_until(lambda: view.drawn is not None and view.drawn.frame.seq == 0, what="frame 0 drawn")
    start = drawn_xy_mm(view, agent)
    assert np.allclose(start, pose_at(0.0), atol=0.5), (start, pose_at(0.0))

    thumb.press("End")
    end_t = timeline.duration
    wait_until(lambda: abs(controls.player.cursor - end_t) < 0.06, what="the cursor at the end")
    last = timeline.frame_index(controls.player.cursor)
    wait_until(
        lambda: view.drawn is not None and view.drawn.frame.seq == last, what="the last frame"
    )
    end = drawn_xy_mm(view, agent)
    assert np.allclose(end, pose_at(controls.player.cursor), atol=0.5)
    assert np.hypot(*(end - start)) > 100, "the recorded robot drove ~80 mm/s for 3 s"

    # A cursor in the middle (as a drag would leave it): drawn at that time's pose.
    thumb.press("Home")
    for _ in range(20):  # 20 steps of 0.05 s
        thumb.press("ArrowRight")
    # Half a step of slack: the page's slider sums 0.05 s steps in floating point.
    wait_until(lambda: abs(controls.player.cursor - 1.0) < 0.026, what="the cursor at 1 s")
    mid = controls.player.cursor
    wait_until(
        lambda: view.drawn is not None and view.drawn.frame.seq == timeline.frame_index(mid),
        what="the frame at 1 s",
    )
    assert np.allclose(drawn_xy_mm(view, agent), pose_at(mid), atol=0.5)
    page.wait_text("t = 1.00 s")  # the readings follow the cursor too

    # Play at 4x runs to the end and stops there.
    page.input_after_label("Speed").click()
    page.p.get_by_role("option", name="4x", exact=True).click()
    wait_until(lambda: controls.player.speed == 4.0, what="4x chosen")
    page.click("Play")
    # The cursor was at 1 s: reaching the end is the proof that it played. At 4x the 2 s
    # left play in 0.5 s, less than a busy machine may leave between two looks (a run
    # with two busy loops beside it missed the playing in between).
    wait_until(lambda: controls.player.at_end, 20, what="the end of the recording")
    assert not controls.player.playing
    page.wait_text("ZeroDivisionError")  # the output up to the cursor, at the end
    page.screenshot("replay")
    # Play at the end starts again from the start, as a media player does; at half speed
    # the 3 s recording plays 6 s, time enough to Pause it on a busy machine (at 4x it
    # could end, and Pause be disabled, before the click landed).
    page.input_after_label("Speed").click()
    page.p.get_by_role("option", name="0.5x", exact=True).click()
    wait_until(lambda: controls.player.speed == 0.5, what="0.5x chosen")
    page.click("Play")
    wait_until(
        lambda: controls.player.playing and controls.player.cursor < timeline.duration,
        10,
        what="playing again from the start",
    )
    wait_until(lambda: float(controls.slider.value) < timeline.duration, 10, what="the slider")
    page.click("Pause")
    wait_until(lambda: not controls.player.playing, 10, what="paused")

    page.click("Back to live")
    wait_until(lambda: view.feed is not None and view.feed is not controls.feed, what="live")
    assert controls.closed and recordings.replay is None
    assert view.feed is not None and view.feed.world == live.world  # type: ignore[union-attr]
    n = view.frames_applied
    wait_until(lambda: view.frames_applied > n + 3, what="live frames again")
