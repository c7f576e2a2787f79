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

from common.tracking.calibration import ArenaCalibration, detect
from common.tracking.markers import MarkerLayout

log = logging.getLogger("wart.tracking")


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
        poses = []
        self._unknown: list[int] = []
        for marker, px in detect(gray).items():
            agent = self.layout.agent_of.get(marker)
            if agent is None:
                if marker not in self.layout.reference:
                    self._unknown.append(marker)
                continue
            ideal = self.calibration.undistort_points(px)
            mm = self.calibration.to_arena(ideal, self.layout.robot_marker_height_mm)
            centre = mm.mean(axis=0)
            # The heading from both of the marker's axes: its up edge pair and its
            # side pair turned a quarter (halves the error of one pair's corners).
            up = (mm[0] + mm[1]) / 2.0 - (mm[2] + mm[3]) / 2.0
            right = (mm[1] + mm[2]) / 2.0 - (mm[0] + mm[3]) / 2.0
            up = up + np.array([-right[1], right[0]])
            side = float(np.mean(np.linalg.norm(np.roll(px, -1, axis=0) - px, axis=1)))
            poses.append(
                TrackedPose(
                    agent=agent,
                    marker=marker,
                    x=float(centre[0]),
                    y=float(centre[1]),
                    heading=math.atan2(float(up[1]), float(up[0])),
                    at=captured_at,
                    side_px=side,
                )
            )
        return poses

    def track(self, frame: np.ndarray, captured_at: float) -> Frame:
        """The poses of this frame that can be trusted, the others held back."""
        accepted: list[TrackedPose] = []
        held: list[str] = []
        for pose in self.detect_poses(frame, captured_at):
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
            track.pose, track.pending = pose, []
            if pose.agent in self._told_jump:
                self._told_jump.discard(pose.agent)
                self._say(f"{pose.agent} is tracked again")
            return True
        # A jump: believe it once it holds still at the new place.
        pending = [p for p in track.pending if math.hypot(p.x - pose.x, p.y - pose.y) <= reach]
        pending.append(pose)
        track.pending = pending
        if len(pending) >= self.confirm_frames:
            track.pose, track.pending = pose, []
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
