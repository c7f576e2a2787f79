"""Robots' poses from a frame: markers found, mapped to the arena, checked against the last.

A pose is published with the frame's capture time. What cannot be trusted is
held back and said once, not per frame: a marker that belongs to no robot, and
a marker that jumped further than a robot can drive (a reflection, a misread
id) until it holds at its new place for ``confirm_frames`` frames (then the
robot really was moved, by hand for instance).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from common.tracking.calibration import ArenaCalibration, detect_all, detector
from common.tracking.deblur import find_blurred
from common.tracking.markers import MarkerLayout

log = logging.getLogger("wart.tracking")

PREDICT_S = 0.5  # a robot is looked for where its last fixes say it went this long
SEARCH_S = 5.0  # and at unread outlines within its reach this long after its last fix
MIN_BLUR_SPEED_MM_S = 60.0  # slower, a marker is not blurred out of reading: covered
MAX_PLACES = 3  # unread outlines tried for one robot, the nearest to its prediction first
LOST_S = 1.0  # unseen this long, a robot is said to be lost (once, with the reason)


@dataclass(frozen=True)
class TrackedPose:
    """One robot seen in one frame: arena mm and radians, at the frame's capture time."""

    agent: str
    marker: int
    x: float
    y: float
    heading: float
    at: float
    side_px: float  # the marker's apparent size: small means far or blurred


@dataclass
class _Track:
    pose: TrackedPose
    pending: list[TrackedPose] = field(default_factory=list)
    velocity: tuple[float, float] = (0.0, 0.0)  # mm/s, from the last two fixes
    lost_told: bool = False

    def trust(self, pose: TrackedPose) -> None:
        dt = pose.at - self.pose.at
        if 0.0 < dt <= PREDICT_S:
            self.velocity = ((pose.x - self.pose.x) / dt, (pose.y - self.pose.y) / dt)
        elif dt > PREDICT_S:
            self.velocity = (0.0, 0.0)
        self.pose, self.pending = pose, []


@dataclass(frozen=True)
class Frame:
    """What one frame gave: the poses to trust, and what was held back."""

    poses: tuple[TrackedPose, ...]
    unknown_markers: tuple[int, ...] = ()
    held_back: tuple[str, ...] = ()


class Tracker:
    """Markers -> robots' poses, for one arena and one camera."""

    def __init__(
        self,
        layout: MarkerLayout,
        calibration: ArenaCalibration,
        *,
        max_speed_mm_s: float = 400.0,
        jump_margin_mm: float = 30.0,
        confirm_frames: int = 3,
        say: Callable[[str], None] | None = None,
    ) -> None:
        self.layout = layout
        self.calibration = calibration
        self.max_speed_mm_s = max_speed_mm_s
        self.jump_margin_mm = jump_margin_mm
        self.confirm_frames = confirm_frames
        self._say = say or log.warning
        self._tracks: dict[str, _Track] = {}
        self._told_unknown: set[int] = set()
        self._told_jump: set[str] = set()

    def detect_poses(self, frame: np.ndarray, captured_at: float) -> list[TrackedPose]:
        """Every robot marker in ``frame`` as a pose, unchecked against earlier frames."""
        # Markers are found in the frame as recorded, their corners then undistorted (the
        # whole frame is not: a 1280x720 remap cost more than the detection).
        gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        self._gray = gray
        poses = []
        self._unknown: list[int] = []
        read, self._unread = detect_all(gray)
        for marker, px in read.items():
            agent = self.layout.agent_of.get(marker)
            if agent is None:
                if marker not in self.layout.reference:
                    self._unknown.append(marker)
                continue
            poses.append(self._pose_of(agent, marker, px, captured_at))
        return poses

    def _pose_of(self, agent: str, marker: int, px: np.ndarray, captured_at: float) -> TrackedPose:
        ideal = self.calibration.undistort_points(px)
        mm = self.calibration.to_arena(ideal, self.layout.robot_marker_height_mm)
        centre = mm.mean(axis=0)
        # The heading from both of the marker's axes: its up edge pair and its
        # side pair turned a quarter (halves the error of one pair's corners).
        up = (mm[0] + mm[1]) / 2.0 - (mm[2] + mm[3]) / 2.0
        right = (mm[1] + mm[2]) / 2.0 - (mm[0] + mm[3]) / 2.0
        up = up + np.array([-right[1], right[0]])
        side = float(np.mean(np.linalg.norm(np.roll(px, -1, axis=0) - px, axis=1)))
        return TrackedPose(
            agent=agent,
            marker=marker,
            x=float(centre[0]),
            y=float(centre[1]),
            heading=math.atan2(float(up[1]), float(up[0])),
            at=captured_at,
            side_px=side,
        )

    def _through_blur(self, seen: set[str], captured_at: float) -> list[TrackedPose]:
        """Robots not read in this frame, looked for through their motion blur: where
        they should be now if they were driving and where they were (fixed less than
        PREDICT_S ago), and at each outline the detector could not read within their
        reach (SEARCH_S). A robot never fixed yet is looked for at the unread outlines."""
        found: list[TrackedPose] = []
        h = self.layout.robot_marker_height_mm
        unread = (
            self.calibration.to_arena(self.calibration.undistort_points(np.array(self._unread)), h)
            if self._unread
            else np.zeros((0, 2))
        )
        for agent, track in self._tracks.items():
            dt = captured_at - track.pose.at
            if agent in seen or not 0.0 < dt <= SEARCH_S:
                continue
            vx, vy = track.velocity if dt <= PREDICT_S else (0.0, 0.0)
            x, y = track.pose.x + vx * dt, track.pose.y + vy * dt
            reach = self.max_speed_mm_s * dt + self.jump_margin_mm
            places = []
            if math.hypot(vx, vy) >= MIN_BLUR_SPEED_MM_S:
                places = [(x, y), (track.pose.x, track.pose.y)]
            near = np.hypot(unread[:, 0] - track.pose.x, unread[:, 1] - track.pose.y) <= reach
            places += sorted(
                (tuple(p) for p in unread[near]), key=lambda p: math.hypot(p[0] - x, p[1] - y)
            )[:MAX_PLACES]
            ahead = np.array([(x, y), (x + vx * 0.01, y + vy * 0.01)])
            way = np.diff(self.calibration.to_frame(ahead, h), axis=0)[0]
            angle = math.atan2(way[1], way[0]) if math.hypot(vx, vy) else None
            for px in self.calibration.to_frame(np.array(places), h) if places else []:
                read = find_blurred(self._gray, detector(), {track.pose.marker}, px, angle)
                if read is not None:
                    found.append(self._pose_of(agent, read[0], read[1], captured_at))
                    break
        untracked = {
            i: a for a, i in self.layout.robots.items() if a not in self._tracks and a not in seen
        }
        for px in self._unread[:MAX_PLACES] if untracked else []:
            read = find_blurred(self._gray, detector(), untracked, px, None)
            if read is not None and read[0] in untracked:
                found.append(self._pose_of(untracked.pop(read[0]), read[0], read[1], captured_at))
        return found

    def _say_lost(self, seen: set[str], captured_at: float) -> None:
        for agent, track in self._tracks.items():
            if agent in seen:
                if track.lost_told:
                    track.lost_told = False
                    self._say(f"{agent} is seen again")
                continue
            unseen = captured_at - track.pose.at
            if unseen >= LOST_S and not track.lost_told:
                track.lost_told = True
                speed = math.hypot(*track.velocity)
                why = (
                    f"it was driving at {speed:.0f} mm/s: blurred beyond reading, or covered"
                    if speed >= MIN_BLUR_SPEED_MM_S
                    else "it stood still: its marker is covered, or it was lifted"
                )
                self._say(
                    f"{agent} lost: not seen for {unseen:.1f} s since "
                    f"({track.pose.x:.0f}, {track.pose.y:.0f}) mm; {why}"
                )

    def track(self, frame: np.ndarray, captured_at: float) -> Frame:
        """The poses of this frame that can be trusted, the others held back."""
        accepted: list[TrackedPose] = []
        held: list[str] = []
        poses = self.detect_poses(frame, captured_at)
        poses += self._through_blur({p.agent for p in poses}, captured_at)
        self._say_lost({p.agent for p in poses}, captured_at)
        for pose in poses:
            if self._accept(pose):
                accepted.append(pose)
            else:
                held.append(pose.agent)
        for marker in self._unknown:
            if marker not in self._told_unknown:
                self._told_unknown.add(marker)
                self._say(f"marker {marker} belongs to no robot of this arena: ignored")
        return Frame(tuple(accepted), tuple(sorted(set(self._unknown))), tuple(held))

    def _accept(self, pose: TrackedPose) -> bool:
        track = self._tracks.get(pose.agent)
        if track is None:
            self._tracks[pose.agent] = _Track(pose)
            return True
        last = track.pose
        dt = max(pose.at - last.at, 0.0)
        reach = self.max_speed_mm_s * dt + self.jump_margin_mm
        if math.hypot(pose.x - last.x, pose.y - last.y) <= reach:
            track.trust(pose)
            if pose.agent in self._told_jump:
                self._told_jump.discard(pose.agent)
                self._say(f"{pose.agent} is tracked again")
            return True
        # A jump: believe it once it holds still at the new place.
        pending = [p for p in track.pending if math.hypot(p.x - pose.x, p.y - pose.y) <= reach]
        pending.append(pose)
        track.pending = pending
        if len(pending) >= self.confirm_frames:
            track.pose, track.pending, track.velocity = pose, [], (0.0, 0.0)
            self._told_jump.discard(pose.agent)
            self._say(
                f"{pose.agent} was moved to ({pose.x:.0f}, {pose.y:.0f}) mm: tracking it there"
            )
            return True
        if pose.agent not in self._told_jump:
            self._told_jump.add(pose.agent)
            jump = math.hypot(pose.x - last.x, pose.y - last.y)
            self._say(
                f"{pose.agent}'s marker jumped {jump:.0f} mm in {dt:.2f} s, further than it can "
                f"drive: ignored until it holds there for {self.confirm_frames} frames"
            )
        return False
