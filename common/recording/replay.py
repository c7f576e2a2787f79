"""A recording on a timeline: what the world, the robot and the controller were at a cursor time.

Pure (no viser, no Zenoh): the page's replay (viewers/web/replay.py) and
``wart replay FILE`` draw from it, and unit tests drive it with a fake clock.

The cursor is seconds since the run's :attr:`Timeline.start` on the log
clock (the context's wall clock when it received each item), the clock
compare.py uses too: ``sim_time`` is the engine's tick count for a simulated
world and the bridge's polling clock for a real one, so it is not the same
clock for every run. Every "at" lookup returns the newest item at or before
the cursor (a sample is in force until the next one), the first item before
the first one (the robot stands where it started).
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from common.messages import WorldSnapshot
from common.recording import schema as s
from common.recording.reader import Recording, RecordingError, Stamped

T = TypeVar("T")

SPEEDS = (0.5, 1.0, 2.0, 4.0)  # what the page offers; any positive speed works


def _at(items: Sequence[Stamped[T]], times: Sequence[float], t: float) -> Stamped[T] | None:
    """The newest item at or before ``t``; the first one before it; None when empty."""
    if not items:
        return None
    i = bisect.bisect_right(times, t) - 1
    return items[max(i, 0)]


def _began(times: Sequence[float], t: float) -> bool:
    """Whether anything happened by ``t`` (no command yet means no command, not the first)."""
    return bool(times) and times[0] <= t


@dataclass(frozen=True)
class Moment:
    """Everything the replay shows at one cursor time."""

    t: float  # the cursor (s since the start)
    index: int  # the frame's index (changes exactly when the drawn frame does)
    frame: s.FrameRecord
    snapshot: WorldSnapshot
    sample: s.SampleRecord | None
    command: s.CommandRecord | None


class Timeline:
    """Lookups by cursor time over one recording's frames, samples, commands and output."""

    def __init__(self, recording: Recording) -> None:
        info = recording.info
        if info is None:  # read_recording refuses these; a hand-made Recording might not
            raise RecordingError(f"{recording.path} holds no run record")
        if not recording.frames:
            raise RecordingError(
                f"{recording.path} has no world frames to replay "
                f"({recording.truncated or 'the run recorded no poses'})"
            )
        if not recording.snapshots:
            raise RecordingError(f"{recording.path} has no snapshot of the world to draw it on")
        self.recording = recording
        self.agent = info.agent
        # The slot's start, or the first frame when the clocks disagree (a frame stamped
        # before the run record would otherwise sit at a negative time).
        self.start = min(info.start, recording.frames[0].t)
        # The frames set the length: the view is what is replayed; what came after the
        # last frame (the recorder's last lines) is shown at the end.
        self.duration = max(0.0, recording.frames[-1].t - self.start)
        self._frame_t = [f.t - self.start for f in recording.frames]
        self._snap_t = [x.t - self.start for x in recording.snapshots]
        self._sample_t = [x.t - self.start for x in recording.samples]
        self._command_t = [x.t - self.start for x in recording.commands]
        self._output_t = [x.t - self.start for x in recording.output]

    def clamp(self, t: float) -> float:
        return min(max(float(t), 0.0), self.duration)

    def frame_index(self, t: float) -> int:
        return max(bisect.bisect_right(self._frame_t, self.clamp(t)) - 1, 0)

    def frame_time(self, index: int) -> float:
        """The cursor time of frame ``index`` (tests, and a slider that snaps to frames)."""
        return self._frame_t[index]

    def at(self, t: float) -> Moment:
        t = self.clamp(t)
        rec = self.recording
        index = self.frame_index(t)
        snapshot = _at(rec.snapshots, self._snap_t, t)
        sample = _at(rec.samples, self._sample_t, t) if _began(self._sample_t, t) else None
        command = _at(rec.commands, self._command_t, t) if _began(self._command_t, t) else None
        assert snapshot is not None  # the constructor refuses a recording without one
        return Moment(
            t=t,
            index=index,
            frame=rec.frames[index].record,
            snapshot=snapshot.record,
            sample=sample.record if sample is not None else None,
            command=command.record if command is not None else None,
        )

    def output_until(self, t: float, lines: int = 20) -> list[tuple[float, str]]:
        """The controller's last ``lines`` printed lines up to ``t`` (time, text)."""
        t = self.clamp(t)
        end = len(self._output_t) if t >= self.duration else bisect.bisect_right(self._output_t, t)
        out = self.recording.output[max(0, end - lines) : end]
        return [(x.t - self.start, x.record.message) for x in out]

    def samples_between(self, t0: float, t1: float) -> list[tuple[float, s.SampleRecord]]:
        """The slot robot's samples in ``[t0, t1]`` (a plot's window that ends at the cursor)."""
        a = bisect.bisect_left(self._sample_t, t0)
        b = bisect.bisect_right(self._sample_t, t1)
        return [(self._sample_t[i], self.recording.samples[i].record) for i in range(a, b)]


class Player:
    """A cursor that moves at ``speed`` while playing; stops (and pauses) at the end.

    The cursor is computed from a clock when asked, not stepped by a thread, so
    a page reads it at whatever rate it draws and a test passes a fake clock.
    """

    def __init__(self, timeline: Timeline, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.timeline = timeline
        self._clock = clock
        self._cursor = 0.0  # where the cursor was at _since
        self._since = clock()
        self.playing = False
        self.speed = 1.0

    @property
    def cursor(self) -> float:
        if not self.playing:
            return self._cursor
        t = self._cursor + (self._clock() - self._since) * self.speed
        if t >= self.timeline.duration:  # the end: stay there, paused
            self._cursor, self.playing = self.timeline.duration, False
            return self._cursor
        return t

    @property
    def at_end(self) -> bool:
        return self.cursor >= self.timeline.duration

    def seek(self, t: float) -> None:
        self._cursor = self.timeline.clamp(t)
        self._since = self._clock()

    def play(self) -> None:
        if self.playing:
            return
        if self.at_end:  # Play at the end starts again, as a media player does
            self._cursor = 0.0
        self._since = self._clock()
        self.playing = True

    def pause(self) -> None:
        self._cursor = self.cursor
        self._since = self._clock()
        self.playing = False

    def set_speed(self, speed: float) -> None:
        if not speed > 0:
            raise ValueError(f"a replay speed must be positive, not {speed}")
        self._cursor = self.cursor  # the time already played keeps the old speed
        self._since = self._clock()
        self.speed = float(speed)

    def moment(self) -> Moment:
        return self.timeline.at(self.cursor)
