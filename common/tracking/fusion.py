"""A real robot's pose: where the camera saw it, carried on by odometry between frames.

Odometry alone drifts (a wheel slips, and the error grows with every metre);
the camera is exact but comes a few times a second, a little late, and loses a
robot under a hand or out of view. Each camera sighting fixes a correction:
the rigid transform that takes the odometry pose at the frame's capture time
onto the seen pose (as a localiser's map-to-odometry transform does). The
robot's pose is that correction applied to its newest odometry pose, so it
moves smoothly between frames and snaps back to the truth at each one.

Sightings and odometry are ordered on one clock, each by when the robot was
where it says (the frame's capture, the counters' reading), not by when it
arrived: either may come late on a loaded host. A sighting's correction is
worked out again with every odometry reading that comes after it (the odometry
at its capture time is then interpolated, no longer guessed), and while the
newest sighting is newer than the newest reading the pose shown is at the
sighting's time, not the odometry's older one: a late odometry reading or a
late frame never makes a robot driving forward step back.

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
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

Source = Literal["tracked", "odometry", "not seen"]
Pose3 = tuple[float, float, float]  # x mm, y mm, heading rad
# Odometry is carried on past its newest reading this long at most (a few of the bridge's
# serial rounds): a robot that stopped meanwhile is not carried further than that.
EXTRAPOLATE_S = 0.2


@dataclass(frozen=True)
class FusedPose:
    x: float
    y: float
    heading: float
    source: Source


def _compose(a: Pose3, b: Pose3) -> Pose3:
    """a ⊕ b: pose b expressed in a's frame, into a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (
        a[0] + c * b[0] - s * b[1],
        a[1] + s * b[0] + c * b[1],
        math.remainder(a[2] + b[2], math.tau),
    )


def _inverse(a: Pose3) -> Pose3:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], -a[2])


@dataclass
class _Robot:
    history: deque[tuple[float, Pose3]] = field(
        default_factory=lambda: deque(maxlen=256)
    )  # (wall time, odometry pose)
    correction: Pose3 = (0.0, 0.0, 0.0)  # the last worked out
    seen_at: float | None = None
    seen_by: str = ""  # the camera of the newest sighting
    last_shown: Pose3 | None = None
    # Each camera's newest sighting: (capture time, the pose seen).
    sightings: dict[str, tuple[float, Pose3]] = field(default_factory=dict)

    def blend(self, fresh_s: float) -> Pose3:
        """The mean of the corrections of the sightings within ``fresh_s`` of the newest
        (headings on the circle), each against the odometry at its capture time as known
        now: one pose where several cameras see the robot. The last correction if none
        can be worked out (no sighting, or its odometry is long gone)."""
        if not self.sightings:
            return self.correction
        newest = max(at for at, _ in self.sightings.values())
        # A sighting older than the odometry kept (readings dropped) is not paired again.
        full = len(self.history) == self.history.maxlen
        recent = []
        for at, seen in self.sightings.values():
            if newest - at > fresh_s or (full and at < self.history[0][0]):
                continue
            odo = odometry_at(self.history, at)
            if odo is not None:
                recent.append(_compose(seen, _inverse(odo)))
        if not recent:
            return self.correction
        heading = math.atan2(
            sum(math.sin(c[2]) for c in recent), sum(math.cos(c[2]) for c in recent)
        )
        # Corrections differ by a few mm and a fraction of a degree: their mean applied to
        # the odometry pose is the mean of the poses each gives, to first order.
        self.correction = (
            sum(c[0] for c in recent) / len(recent),
            sum(c[1] for c in recent) / len(recent),
            heading,
        )
        return self.correction


class CameraClock:
    """A camera's capture stamps on this machine's clock.

    The camera stamps each frame with its own host's clock; the bridge's
    odometry is on the bridge's. Two machines' clocks differ (by seconds
    without NTP), and a stamp from the future or the past would pair a
    sighting with the wrong odometry pose. Each message's arrival minus the
    camera's stamp of when it sent it is the clocks' difference plus the
    network's delay; the smallest of the recent ones is the difference plus
    the least delay (as NTP's filter takes the least-delayed sample): that is
    added to each capture stamp.

    Not arrival minus capture: that holds the frame's processing too (reading,
    finding the markers: 50 ms and more on a loaded host, never less), so every
    sighting was taken as that much later than it was and paired with odometry
    from after it: the shown pose lagged, and stepped back at every sighting.
    A camera that does not say when it sent (an older one) is timed by its
    capture stamps as before.
    """

    def __init__(self, frames: int = 200) -> None:
        self._gaps: deque[float] = deque(maxlen=frames)
        self._by_sent: bool | None = None

    def local(self, captured_at: float, arrived_at: float, sent_at: float | None = None) -> float:
        """``captured_at`` (the camera's clock) on this clock; ``arrived_at`` is now, here;
        ``sent_at`` when the camera sent it, on its clock (None: not said)."""
        by_sent = sent_at is not None
        if by_sent != self._by_sent:  # a camera restarted as another version: start over
            self._gaps.clear()
            self._by_sent = by_sent
        self._gaps.append(arrived_at - (captured_at if sent_at is None else sent_at))
        return captured_at + min(self._gaps)


class PoseFusion:
    """Odometry and camera sightings of one world's robots, fused per robot.

    Thread-safe: the robots' I/O threads give odometry, the network's thread sightings,
    the frame thread asks for poses (a sighting's correction is worked out again from
    the odometry kept, which must not grow while it is read)."""

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
        self._lock = threading.Lock()

    def _robot(self, agent: str) -> _Robot:
        return self._robots.setdefault(agent, _Robot())

    def odometry(self, agent: str, x: float, y: float, heading: float, at: float) -> None:
        """The robot's odometry pose (the bridge's integration) at wall time ``at``: when
        the robot was there (its counters read), not when the bridge heard of it. The same
        reading given again (the robot's other news: online, LEDs) is not a new one: it
        would say the robot stood still since."""
        with self._lock:
            history = self._robot(agent).history
            if not history or history[-1][0] != at:
                history.append((at, (x, y, heading)))

    def camera_alive(self, at: float) -> None:
        """The camera spoke (a frame of tracked poses, even an empty one)."""
        with self._lock:
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
        with self._lock:
            robot = self._robot(agent)
            if odometry_at(robot.history, captured_at) is None:
                return False
            robot.sightings[camera] = (captured_at, (x, y, heading))
            if robot.seen_at is None or captured_at >= robot.seen_at:
                robot.seen_at, robot.seen_by = captured_at, camera
            return True

    def camera_gone(self) -> None:
        """The last camera's process is gone (its presence token left): offline at once."""
        with self._lock:
            self._camera_at = None

    def camera_left(self, camera: str) -> None:
        """One camera's process is gone while others live: the robots it saw last, and no
        other since, are on odometry (their camera is offline), not "not seen"."""
        with self._lock:
            self._camera_left(camera)

    def _camera_left(self, camera: str) -> None:
        self._left.add(camera)
        for robot in self._robots.values():
            if camera not in robot.sightings:
                continue
            robot.blend(self.fresh_s)  # the correction with it, kept if no other holds it
            del robot.sightings[camera]
            if not robot.sightings:
                continue
            other = max(robot.sightings, key=lambda c: robot.sightings[c][0])
            at = robot.sightings[other][0]
            if robot.seen_at is not None and robot.seen_at - at <= self.fresh_s:
                # Another camera saw it as recently (the overlap): that one holds it.
                robot.seen_by, robot.seen_at = other, at
            else:
                # Another camera saw it long ago: its old correction is not taken back.
                robot.sightings.clear()

    def camera_back(self, camera: str) -> None:
        with self._lock:
            self._left.discard(camera)

    def sighting_age(self, agent: str, now: float) -> float | None:
        """How old the last sighting of ``agent`` is, if the camera that made it still runs
        (None: never seen, or that camera's process has gone)."""
        with self._lock:
            robot = self._robots.get(agent)
            if robot is None or robot.seen_at is None or robot.seen_by in self._left:
                return None
            return now - robot.seen_at

    def camera_live(self, now: float) -> bool:
        camera_at = self._camera_at
        return camera_at is not None and now - camera_at <= self.camera_silent_after_s

    def pose(self, agent: str, now: float) -> FusedPose | None:
        with self._lock:
            return self._pose(agent, now)

    def _pose(self, agent: str, now: float) -> FusedPose | None:
        robot = self._robots.get(agent)
        if robot is None or not robot.history:
            return None
        at, odo = robot.history[-1]
        camera = self.camera_live(now) and robot.seen_by not in self._left
        if camera and (robot.seen_at is None or now - robot.seen_at > self.unseen_after_s):
            if robot.last_shown is not None:  # kept where it was last trusted
                return FusedPose(*robot.last_shown, source="not seen")
            return FusedPose(*self._inside(odo), source="not seen")
        if robot.sightings and robot.seen_at is not None and robot.seen_at > at:
            # The camera is ahead of the odometry (the bridge's serial round is late): the
            # pose where the camera saw it, not where the older odometry reading says.
            odo = odometry_at(robot.history, robot.seen_at) or odo
        shown = self._inside(_compose(robot.blend(self.fresh_s), odo))
        robot.last_shown = shown
        fresh = robot.seen_at is not None and now - robot.seen_at <= self.fresh_s
        return FusedPose(*shown, source="tracked" if camera and fresh else "odometry")

    def _inside(self, pose: tuple[float, float, float]) -> tuple[float, float, float]:
        r = self.radius_mm
        x = min(max(pose[0], r), max(r, self.width_mm - r))
        y = min(max(pose[1], r), max(r, self.height_mm - r))
        return (x, y, pose[2])


def odometry_at(history: Sequence[tuple[float, Pose3]], t: float) -> Pose3 | None:
    """The odometry pose at ``t``, linearly between the two readings around it; after
    the newest, carried on at the speed of the last two for up to EXTRAPOLATE_S.

    A sighting newer than the newest reading (the bridge's serial round is late, the
    camera's is not) paired with that older reading took the robot's drive since as
    the odometry's error: the shown pose ran ahead by it until the next sighting
    pulled it back, a robot driving forward shown stepping back."""
    if not history or t < history[0][0] - 0.5:
        return None
    times = [h[0] for h in history]
    i = bisect.bisect_left(times, t)
    if i == 0:
        return history[0][1]
    if i >= len(history):
        if len(history) < 2:
            return history[-1][1]
        (t0, a), (t1, b) = history[-2], history[-1]
        t = min(t, t1 + EXTRAPOLATE_S)
    else:
        (t0, a), (t1, b) = history[i - 1], history[i]
    f = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
    dh = math.remainder(b[2] - a[2], math.tau)
    return (
        a[0] + f * (b[0] - a[0]),
        a[1] + f * (b[1] - a[1]),
        math.remainder(a[2] + f * dh, math.tau),
    )
