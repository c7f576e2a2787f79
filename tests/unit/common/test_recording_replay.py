"""The replay timeline: what was at a cursor time, play at a speed, stop at the end."""

from __future__ import annotations

from pathlib import Path

import pytest

from common.recording import RecordingError, read_recording
from common.recording import schema as s
from common.recording.reader import Recording
from common.recording.replay import Player, Timeline
from tests.unit.common.test_recording import _record


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    _record(path, seconds=2.0)
    return read_recording(path)


def _x(timeline: Timeline, t: float) -> float:
    moment = timeline.at(t)
    return moment.frame.x[moment.frame.rows.index(timeline.agent)]


def test_the_frame_at_a_cursor_is_the_newest_at_or_before_it(recording: Recording) -> None:
    timeline = Timeline(recording)
    assert 1.5 < timeline.duration < 2.5
    n = len(recording.frames)
    # Exactly at a frame's time: that frame; just before the next: still that one.
    for i in (0, 1, n // 2, n - 1):
        t = timeline.frame_time(i)
        assert timeline.at(t).index == i
        assert timeline.at(t).frame is recording.frames[i].record
    mid = timeline.frame_time(n // 2)
    nxt = timeline.frame_time(n // 2 + 1)
    assert timeline.at((mid + nxt) / 2).index == n // 2
    # The robot drives straight ahead: later cursor, further along.
    assert _x(timeline, 0.0) < _x(timeline, timeline.duration / 2) < _x(timeline, 1e9)
    # Outside the run: clamped to its first and last frame, never an error.
    assert timeline.at(-5.0).index == 0 and timeline.at(-5.0).t == 0.0
    assert timeline.at(1e9).index == n - 1 and timeline.at(1e9).t == timeline.duration
    # The snapshot, the sample and the command in force follow the cursor too.
    moment = timeline.at(mid)
    assert moment.snapshot is recording.snapshot
    assert moment.sample is not None and moment.command is not None
    assert moment.command.speeds == (10, 10)


def test_output_lines_appear_as_the_cursor_reaches_them(recording: Recording) -> None:
    timeline = Timeline(recording)
    # The fixture prints its lines after its last frame: the end of the replay shows them.
    lines = [text for _, text in timeline.output_until(timeline.duration)]
    assert lines[0] == "hello" and lines[-1].startswith("ZeroDivisionError")
    assert [text for _, text in timeline.output_until(timeline.duration, lines=2)] == lines[-2:]
    window = timeline.samples_between(0.5, 1.0)
    assert window and all(0.5 <= t <= 1.0 for t, _ in window)


def test_play_moves_the_cursor_at_its_speed_and_stops_at_the_end(recording: Recording) -> None:
    clock = FakeClock()
    player = Player(Timeline(recording), clock=clock)
    assert player.cursor == 0.0 and not player.playing
    player.play()
    clock.now += 0.5
    assert player.cursor == pytest.approx(0.5)
    player.set_speed(2.0)  # the half second already played stays played
    clock.now += 0.25
    assert player.cursor == pytest.approx(1.0)
    player.pause()
    clock.now += 10.0
    assert player.cursor == pytest.approx(1.0)  # paused: the clock moves, the cursor not
    player.set_speed(4.0)
    player.play()
    clock.now += 10.0  # far past the end at 4x
    assert player.cursor == player.timeline.duration
    assert player.at_end and not player.playing
    assert player.moment().index == len(recording.frames) - 1
    player.play()  # Play at the end starts again from the start
    assert player.playing and player.cursor == 0.0
    player.seek(0.75)
    clock.now += 0.125
    assert player.cursor == pytest.approx(0.75 + 0.5)
    with pytest.raises(ValueError):
        player.set_speed(0.0)


def test_a_recording_without_frames_is_refused_in_words(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    writer = _record(path, seconds=0.0)
    assert writer.closed
    rec = read_recording(path)
    assert rec.frames == []
    with pytest.raises(RecordingError, match="no world frames to replay"):
        Timeline(rec)
    assert s.FRAME in rec.channels  # the channel is declared, just empty
