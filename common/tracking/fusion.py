"""A real robot's pose: where the camera saw it, carried on by odometry between frames.

Odometry alone drifts (a wheel slips, and the error grows with every metre);
the camera is exact but comes a few times a second, a little late, and loses a
robot under a hand or out of view. Each camera sighting fixes a correction:
the rigid transform that takes the odometry pose at the frame's capture time
onto the seen pose (as a localiser's map-to-odometry transform does). The
robot's pose is that correction applied to its current odometry pose, so it
moves smoothly between frames and snaps back to the truth at each one.

Several cameras may share one arena (one per half, overlapping at the seam).
Each keeps its own latest correction per robot; the robot's is the mean of the
corrections of the cameras that saw it within ``fresh_s`` of the newest
sighting, so a robot in the overlap has one pose (not one per camera, taken in
turns), and leaving one camera's view for the other's shifts it by half the
two cameras' disagreement at most, never to "not seen".

What is shown is honest about its source: ``tracked`` (seen within
``fresh_s``), ``odometry`` (no camera over this arena, the camera is
offline, or the camera that saw it last has gone and no other has seen it
since: the world says so), or ``not seen`` (a live camera has not seen this
robot for ``unseen_after_s``): then the last trusted pose is kept, never a
guess, and every pose is kept inside the arena.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from dataclasses import dataclass, field
from typing import Literal

Source = Literal["tracked", "odometry", "not seen"]


@dataclass(frozen=True)
class FusedPose:
    x: float
    y: float
    heading: float
    source: Source


def _compose(
    a: tuple[float, float, float], b: tuple[float, float, float]
) -> tuple[float, float, float]:
    """a ⊕ b: pose b expressed in a's frame, into a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (
        a[0] + c * b[0] - s * b[1],
        a[1] + s * b[0] + c * b[1],
        math.remainder(a[2] + b[2], math.tau),
    )


def _inverse(a: tuple[float, float, float]) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2])


@dataclass
class _Robot:
    history: deque[tuple[float, tuple[float, float, float]]] = field(
        default_factory=lambda: deque(maxlen=256)
    )  # (wall time, odometry pose)
    correction: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seen_at: float | None = None
    seen_by: str = ""  # the camera of the newest sighting
    last_shown: tuple[float, float, float] | None = None
    # Each camera's newest sighting: (capture time, its correction).
    sightings: dict[str, tuple[float, tuple[float, float, float]]] = field(default_factory=dict)

    def blend(self, fresh_s: float) -> tuple[float, float, float]:
        """The mean of the corrections seen within ``fresh_s`` of the newest (headings on
        the circle): one pose where several cameras see the robot."""
        newest = max(at for at, _ in self.sightings.values())
        recent = [c for at, c in self.sightings.values() if newest - at <= fresh_s]
        if len(recent) == 1:
            return recent[0]
        heading = math.atan2(
            sum(math.sin(c[2]) for c in recent), sum(math.cos(c[2]) for c in recent)
        )
        # Corrections differ by a few mm and a fraction of a degree: their mean applied to
        # the odometry pose is the mean of the poses each gives, to first order.
        return (
            sum(c[0] for c in recent) / len(recent),
            sum(c[1] for c in recent) / len(recent),
            heading,
        )


class CameraClock:
    """A camera's capture stamps on this machine's clock.

    The camera stamps each frame with its own host's clock; the bridge's
    odometry is on the bridge's. Two machines' clocks differ (by seconds
    without NTP), and a stamp from the future or the past would pair a
    sighting with the wrong odometry pose. Each frame's arrival minus its
    stamp is the clocks' difference plus the frame's delay; the smallest of
    the recent ones is the difference plus the least delay (as NTP's filter
    takes the least-delayed sample): that is added to each stamp.
    """

    def __init__(self, frames: int = 200) -> None:
        self._gaps: deque[float] = deque(maxlen=frames)

    def local(self, captured_at: float, arrived_at: float) -> float:
        """``captured_at`` (the camera's clock) on this clock; ``arrived_at`` is now, here."""
        self._gaps.append(arrived_at - captured_at)
        return captured_at + min(self._gaps)


class PoseFusion:
    """Odometry and camera sightings of one world's robots, fused per robot."""

    def __init__(
        self,
        width_mm: float,
        height_mm: float,
        *,
        radius_mm: float = 27.5,
        fresh_s: float = 0.5,
        unseen_after_s: float = 1.0,
        camera_silent_after_s: float = 2.0,
    ) -> None:
        self.width_mm, self.height_mm, self.radius_mm = width_mm, height_mm, radius_mm
        self.fresh_s, self.unseen_after_s = fresh_s, unseen_after_s
        self.camera_silent_after_s = camera_silent_after_s
        self._robots: dict[str, _Robot] = {}
        self._camera_at: float | None = None  # the last camera message of any kind
        self._left: set[str] = set()  # cameras whose process has gone (others live on)

    def _robot(self, agent: str) -> _Robot:
        return self._robots.setdefault(agent, _Robot())

    def odometry(self, agent: str, x: float, y: float, heading: float, at: float) -> None:
        """The robot's odometry pose (the bridge's integration) at wall time ``at``."""
        self._robot(agent).history.append((at, (x, y, heading)))

    def camera_alive(self, at: float) -> None:
        """The camera spoke (a frame of tracked poses, even an empty one)."""
        self._camera_at = at if self._camera_at is None else max(self._camera_at, at)

    def seen(
        self,
        agent: str,
        x: float,
        y: float,
        heading: float,
        captured_at: float,
        camera: str = "",
    ) -> bool:
        """``camera`` saw ``agent`` there at ``captured_at``; False if no odometry covers it
        yet. Whether the camera is alive is the caller's word (``camera_alive``), by arrival."""
        robot = self._robot(agent)
        odo = self._odometry_at(robot, captured_at)
        if odo is None:
            return False
        robot.sightings[camera] = (captured_at, _compose((x, y, heading), _inverse(odo)))
        robot.correction = robot.blend(self.fresh_s)
        if robot.seen_at is None or captured_at >= robot.seen_at:
            robot.seen_at, robot.seen_by = captured_at, camera
        return True

    def camera_gone(self) -> None:
        """The last camera's process is gone (its presence token left): offline at once."""
        self._camera_at = None

    def camera_left(self, camera: str) -> None:
        """One camera's process is gone while others live: the robots it saw last, and no
        other since, are on odometry (their camera is offline), not "not seen"."""
        self._left.add(camera)
        for robot in self._robots.values():
            if robot.sightings.pop(camera, None) is None or not robot.sightings:
                continue
            other = max(robot.sightings, key=lambda c: robot.sightings[c][0])
            at = robot.sightings[other][0]
            if robot.seen_at is not None and robot.seen_at - at <= self.fresh_s:
                # Another camera saw it as recently (the overlap): that one holds it.
                robot.correction = robot.blend(self.fresh_s)
                robot.seen_by, robot.seen_at = other, at
            # Else another camera saw it long ago: its old correction is not taken back.

    def camera_back(self, camera: str) -> None:
        self._left.discard(camera)

    def camera_live(self, now: float) -> bool:
        return self._camera_at is not None and now - self._camera_at <= self.camera_silent_after_s

    def pose(self, agent: str, now: float) -> FusedPose | None:
        robot = self._robots.get(agent)
        if robot is None or not robot.history:
            return None
        odo = robot.history[-1][1]
        camera = self.camera_live(now) and robot.seen_by not in self._left
        if camera and (robot.seen_at is None or now - robot.seen_at > self.unseen_after_s):
            if robot.last_shown is not None:  # kept where it was last trusted
                return FusedPose(*robot.last_shown, source="not seen")
            return FusedPose(*self._inside(odo), source="not seen")
        shown = self._inside(_compose(robot.correction, odo))
        robot.last_shown = shown
        fresh = robot.seen_at is not None and now - robot.seen_at <= self.fresh_s
        return FusedPose(*shown, source="tracked" if camera and fresh else "odometry")

    def _inside(self, pose: tuple[float, float, float]) -> tuple[float, float, float]:
        r = self.radius_mm
        x = min(max(pose[0], r), max(r, self.width_mm - r))
        y = min(max(pose[1], r), max(r, self.height_mm - r))
        return (x, y, pose[2])

    @staticmethod
    def _odometry_at(robot: _Robot, t: float) -> tuple[float, float, float] | None:
        """The odometry pose at ``t``, linearly between the two readings around it."""
        history = robot.history
        if not history or t < history[0][0] - 0.5:
            return None
        times = [h[0] for h in history]
        i = bisect.bisect_left(times, t)
        if i == 0:
            return history[0][1]
        if i >= len(history):
            return history[-1][1]
        (t0, a), (t1, b) = history[i - 1], history[i]
        f = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        dh = math.remainder(b[2] - a[2], math.tau)
        return (
            a[0] + f * (b[0] - a[0]),
            a[1] + f * (b[1] - a[1]),
            math.remainder(a[2] + f * dh, math.tau),
        )
