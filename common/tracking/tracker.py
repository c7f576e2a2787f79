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
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from common.tracking.calibration import ArenaCalibration, detect_all
from common.tracking.deblur import (
    AXES,
    BLUR_LENGTHS_PX,
    OUTLINE_WINDOW_PX,
    WIDE_WINDOW_PX,
    WINDOW_PX,
    Readings,
    find_blurred,
)
from common.tracking.markers import MarkerLayout, corners_mm
from common.tracking.refine import refine_corners

log = logging.getLogger("wart.tracking")

PREDICT_S = 0.5  # a robot is looked for where its last fixes say it went this long
SEARCH_S = 5.0  # and at unread outlines within its reach this long after its last fix
MIN_BLUR_SPEED_MM_S = 60.0  # slower, a marker is not blurred out of reading: covered
MAX_PLACES = 3  # unread outlines tried for one robot, the nearest to its prediction first
# An unread outline is a marker's when its side is this fraction of a marker's there
# (blur lengthens it, the robot's dark side merges with it; clutter is far off).
MARKER_LIKE = (0.6, 2.2)
# A marker smeared along its way and half merged with its robot's dark side is often
# outlined by its core alone, 0.4 to 0.5 of its side (the robot lost at 320 mm/s after
# turning at a wall, seeds 2 and 3): such outlines are looked at for a robot that was
# tracked, within its reach, not in the search for robots never fixed.
SMEARED_LIKE = 0.4
# A fast robot read nowhere is looked for around where it was this long after its fix
# (two frames at 15 fps): the wide window costs about 120 ms of CPU when it does not read.
WIDE_S = 0.15
LOST_S = 1.0  # unseen this long, a robot is said to be lost (once, with the reason)
# Smeared less than this, a marker in view is read by the detector itself (200 mm/s, 4.4 px
# on the bench's 1/25 s: 100 %): such a robot unread is covered, not blurred.
READABLE_BLUR_PX = 3.0
BLUR_SPREAD_PX = 1.5  # deblurred at lengths this near the smear its speed predicts


def threshold_window_px(cell_px: float) -> int:
    """The smallest neighbourhood (px) a frame is thresholded over, for marker cells of
    ``cell_px`` at the narrowest: 13 (then 23) for cells of 2.5 px or more, else 3 (then 13
    and 23). A 3 px neighbourhood inside a wider cell sets the cell's pixels against the cell
    itself: it outlines noise and bit edges, not markers. Without it, detection, position and
    heading held on bench seeds 1, 2 and 3 at 18 degrees (3.1 px cells), 1 and 2 at 25 (2.7
    px), 2 at 10, and on the synthetic camera at 640x480 (2.9 px), for 1 to 4 ms less a frame;
    smaller cells were not measured."""
    return 13 if cell_px >= 2.5 else 3


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
    fixes: int = 1  # fixes in a row: one, and where it goes is not known yet
    blur_px: float | None = None  # the smear's length that read it last

    # Its speeds (when, mm/s) over the last second: a robot that slowed at a wall, or
    # for a turn, may drive on as fast as it did.
    speeds: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=32))

    def trust(self, pose: TrackedPose) -> None:
        self.fixes += 1
        dt = pose.at - self.pose.at
        if 0.0 < dt <= PREDICT_S:
            self.velocity = ((pose.x - self.pose.x) / dt, (pose.y - self.pose.y) / dt)
            self.speeds.append((pose.at, math.hypot(*self.velocity)))
        elif dt > PREDICT_S:
            self.velocity, self.fixes = (0.0, 0.0), 1
        self.pose, self.pending = pose, []

    def top_speed(self) -> float:
        """The fastest it drove (mm/s) in the second before its last fix."""
        return max((v for at, v in self.speeds if self.pose.at - at <= 1.0), default=0.0)


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
        self._scan = 0  # where the search for robots never fixed goes on, among outlines
        # The camera's exposure as the smears read show it: each robot read through its
        # blur gives its smear's length over its speed (px over px/s); the median of the
        # last few tells how far any robot is smeared, from its speed.
        self._exposures: deque[float] = deque(maxlen=15)
        self._exposure: float | None = None  # their median, worked out once a change
        self._threshold_window_px = threshold_window_px(self._smallest_cell_px())

    def detect_poses(self, frame: np.ndarray, captured_at: float) -> list[TrackedPose]:
        """Every robot marker in ``frame`` as a pose, unchecked against earlier frames."""
        # Markers are found in the frame as recorded, their corners then undistorted (the
        # whole frame is not: a 1280x720 remap cost more than the detection).
        gray = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        self._gray = gray
        poses = []
        self._unknown: list[int] = []
        read, self._unread = detect_all(gray, self._threshold_window_px)
        for marker, px in read.items():
            agent = self.layout.agent_of.get(marker)
            if agent is None:
                if marker not in self.layout.reference:
                    self._unknown.append(marker)
                continue
            poses.append(self._pose_of(agent, marker, px, captured_at))
        return poses

    def _pose_of(self, agent: str, marker: int, px: np.ndarray, captured_at: float) -> TrackedPose:
        # The outline's corners, refined by the marker's whole pattern (common/tracking/
        # refine.py): a heading from the outline alone was up to a degree off.
        px = refine_corners(self._gray, marker, px)
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

    def _smallest_cell_px(self) -> float:
        """The narrowest a robot marker's cell (a sixth of its side, border included) is
        in the frame: at the reference markers, the arena's corners."""
        corners = np.array(list(self.layout.reference.values()), dtype=np.float64)
        return float(self._marker_sides_px(corners).min()) / 6.0

    def _marker_sides_px(self, centres: np.ndarray) -> np.ndarray:
        """A robot marker's side (px) in the frame at each arena point (x, y) mm (one
        projection for them all)."""
        side = self.layout.robot_marker_mm
        if not len(centres):
            return np.zeros(0)
        edges = np.vstack([corners_mm(x, y, 0.0, side)[:2] for x, y in centres])
        px = self.calibration.to_frame(edges, self.layout.robot_marker_height_mm)
        ends = px.reshape(-1, 2, 2)
        return np.asarray(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1))

    def _outlines(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The unread outlines that could be a robot's marker, smeared or not: their
        centres in arena mm (at a marker's height) and in frame px, a marker's side there
        (px) and their side's part of it, the likeliest first (nearest a marker's side)."""
        h = self.layout.robot_marker_height_mm
        if not self._unread:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0)
        corners = np.array(self._unread)
        centres_px = corners.mean(axis=1)
        centres = self.calibration.to_arena(self.calibration.undistort_points(centres_px), h)
        sides = np.linalg.norm(np.roll(corners, -1, axis=1) - corners, axis=2).mean(axis=1)
        expected = self._marker_sides_px(centres)
        ratio = sides / np.maximum(expected, 1e-6)
        like = (ratio >= SMEARED_LIKE) & (ratio <= MARKER_LIKE[1])
        order = np.argsort(np.abs(np.log(np.maximum(ratio[like], 1e-6))))
        return (
            centres[like][order],
            centres_px[like][order],
            expected[like][order],
            ratio[like][order],
        )

    def _through_blur(self, seen: set[str], captured_at: float) -> list[TrackedPose]:
        """Robots not read in this frame, looked for through their motion blur: where
        they should be now if they were driving and where they were (fixed less than
        PREDICT_S ago), and at each marker-like outline the detector could not read
        within their reach (SEARCH_S). A robot never fixed yet is looked for at the
        marker-like unread outlines, a few a frame, in turn."""
        found: list[TrackedPose] = []
        h = self.layout.robot_marker_height_mm
        unread, unread_px, unread_side, unread_part = self._outlines()
        readings: Readings = {}
        for agent, track in self._tracks.items():
            dt = captured_at - track.pose.at
            if agent in seen or not 0.0 < dt <= SEARCH_S:
                continue
            vx, vy = track.velocity if dt <= PREDICT_S else (0.0, 0.0)
            x, y = track.pose.x + vx * dt, track.pose.y + vy * dt
            reach = self.max_speed_mm_s * dt + self.jump_margin_mm
            places: list[tuple[np.ndarray, int]] = []
            ahead = np.array([(x, y), (x + vx * 0.01, y + vy * 0.01)])
            way = np.diff(self.calibration.to_frame(ahead, h), axis=0)[0]
            angle = math.atan2(way[1], way[0]) if math.hypot(vx, vy) else None
            # Its speed in px/s, when it drives (a robot standing, or unseen long, is looked
            # for at every length: it may have started since).
            driving = math.hypot(vx, vy) >= MIN_BLUR_SPEED_MM_S
            speed = math.hypot(vx, vy)
            speed_px = math.hypot(*way) / 0.01 * track.top_speed() / speed if driving else 0.0
            lengths, smeared = self._blur_lengths(speed_px, track.blur_px)
            if driving and smeared:
                # Where it went, and where it was. A robot smeared too little to need this
                # is read by the detector where it is in view (unread: covered, or its bits
                # misread, when the outline there is looked at).
                predicted = self.calibration.to_frame(
                    np.array([(x, y), (track.pose.x, track.pose.y)]), h
                )
                places = [(px, WINDOW_PX) for px in predicted]
            elif track.fixes == 1 and dt <= PREDICT_S:
                # Found once (through its blur, maybe): not yet known to stand still.
                last = self.calibration.to_frame(np.array([(track.pose.x, track.pose.y)]), h)
                places = [(last[0], OUTLINE_WINDOW_PX)]
            near = np.flatnonzero(
                np.hypot(unread[:, 0] - track.pose.x, unread[:, 1] - track.pose.y) <= reach
            )
            nearest = sorted(near, key=lambda k: math.hypot(unread[k, 0] - x, unread[k, 1] - y))
            places += [(unread_px[k], OUTLINE_WINDOW_PX) for k in nearest[:MAX_PLACES]]
            side = track.pose.side_px
            done: list[tuple[np.ndarray, int]] = []
            for px, size in places:
                # A marker there lies wholly in a window read already (a robot lost for a
                # frame is a few px from its last place): not read twice.
                if any(np.max(np.abs(px - c)) + side / 2 <= w / 2 for c, w in done):
                    continue
                done.append((px, size))
                read = find_blurred(
                    self._gray, {track.pose.marker}, px, angle, side, size, lengths, (), readings
                )
                if read is not None:
                    break
            else:
                read = None
                if driving and smeared and dt <= WIDE_S:
                    # It turned: around where it was, just after (a window costs 120 ms).
                    b = track.blur_px or 6.0
                    at = self.calibration.to_frame(np.array([(track.pose.x, track.pose.y)]), h)
                    read = find_blurred(
                        self._gray,
                        {track.pose.marker},
                        at[0],
                        None,
                        side,
                        WIDE_WINDOW_PX,
                        (b, b - 0.5, b + 0.5),
                        AXES,
                        readings,
                    )
            if read is not None and driving:
                self._exposures.append(read[2] / (math.hypot(*way) / 0.01))
                self._exposure = None
            if read is not None:
                track.blur_px = read[2]
                found.append(self._pose_of(agent, read[0], read[1], captured_at))
        untracked = {
            i: a for a, i in self.layout.robots.items() if a not in self._tracks and a not in seen
        }
        whole = unread_part >= MARKER_LIKE[0]
        unread_px, unread_side = unread_px[whole], unread_side[whole]
        if untracked and len(unread_px):
            # In turn over the frames: a robot that is not in the arena costs a few windows
            # a frame, not one for every outline.
            start = self._scan % len(unread_px)
            self._scan += MAX_PLACES
            for k in range(start, start + min(MAX_PLACES, len(unread_px))):
                px, side = unread_px[k % len(unread_px)], unread_side[k % len(unread_px)]
                read = find_blurred(
                    self._gray, untracked, px, None, side, OUTLINE_WINDOW_PX, readings=readings
                )
                if read is not None and read[0] in untracked:
                    found.append(
                        self._pose_of(untracked.pop(read[0]), read[0], read[1], captured_at)
                    )
        return found

    def _blur_lengths(self, speed_px: float, last: float | None) -> tuple[Sequence[float], bool]:
        """The smear lengths to deblur a robot driving at ``speed_px`` (px/s; 0: not known)
        at, the one that read it ``last`` first, and whether it may be smeared beyond the
        detector's reading, by the exposure seen so far (every length, and yes, while the
        exposure or the speed is not known)."""
        if not self._exposures or speed_px <= 0.0:
            return BLUR_LENGTHS_PX, True
        if self._exposure is None:
            self._exposure = float(np.median(self._exposures))
        expected = self._exposure * speed_px
        by_nearness = sorted(BLUR_LENGTHS_PX, key=lambda b: abs(b - expected))
        near = [b for b in by_nearness if abs(b - expected) <= BLUR_SPREAD_PX]
        lengths = near or by_nearness[:3]
        if last is not None:
            lengths = [last, *(b for b in lengths if b != last)]
        return lengths, expected >= READABLE_BLUR_PX

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
