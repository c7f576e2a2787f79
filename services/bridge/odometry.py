"""Odometry of a real Khepera: a pose from its wheels' position counters.

Each step between two readings is an arc (differential drive), moved by its
chord along the midpoint heading; a counter jump faster than any wheel can
turn is a reset, not a movement.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

log = logging.getLogger("wart.bridge.robot")


@dataclass(frozen=True)
class Pose:
    """Odometry estimate in the robot's start frame: mm, mm, radians (counter-clockwise)."""

    x: float = 0.0
    y: float = 0.0
    heading: float = 0.0


class Odometry:
    """Pose from position-counter deltas (differential drive, each step an arc)."""

    # Faster than any wheel can turn (127 pulses/10 ms) with a wide margin: a
    # jump this large means the counters were reset, not that the robot moved.
    MAX_PULSES_PER_S = 127 * 100 * 2
    # The readings' times are the host's, when each answer came: on a busy host one answer
    # comes late and the next on time, so two readings 0.1 s apart by the host's clock can
    # hold 0.5 s of the robot's travel (a fresh-clone run at load 14 lost an arc so).
    READ_DELAY_S = 1.0

    def __init__(self, mm_per_pulse: float, wheel_base_mm: float) -> None:
        self.mm_per_pulse, self.wheel_base_mm = mm_per_pulse, wheel_base_mm
        self.pose = Pose()
        self._last: tuple[int, int, float] | None = None

    def rebaseline(self, counters: tuple[int, int] | None = None, now: float = 0.0) -> None:
        """Take ``counters`` as the reference the next reading is measured from.

        Without counters the reference is forgotten and the next reading only sets
        it (the counters changed in a way nobody read, e.g. a reboot).
        """
        self._last = None if counters is None else (counters[0], counters[1], now)

    def set_pose(self, pose: Pose) -> None:
        self.pose = pose

    def update(self, left: int, right: int, now: float) -> Pose:
        last, self._last = self._last, (left, right, now)
        if last is None:
            return self.pose
        dl_p, dr_p = _delta32(left, last[0]), _delta32(right, last[1])
        limit = self.MAX_PULSES_PER_S * (max(now - last[2], 0.0) + self.READ_DELAY_S)
        if abs(dl_p) > limit or abs(dr_p) > limit:
            log.warning("counters jumped by (%d, %d): taken as a reset, pose kept", dl_p, dr_p)
            return self.pose
        dl, dr = dl_p * self.mm_per_pulse, dr_p * self.mm_per_pulse
        d, dth = (dl + dr) / 2, (dr - dl) / self.wheel_base_mm
        mid = self.pose.heading + dth / 2
        # The chord of the arc, not its length: exact for wheels at constant speeds
        # between two readings, however far apart (a busy host reads late; at
        # 40/60 pulses a 0.3 s gap put the arc-length estimate 4 mm out).
        half = dth / 2
        chord = d if abs(half) < 1e-9 else d * math.sin(half) / half
        self.pose = Pose(
            self.pose.x + chord * math.cos(mid),
            self.pose.y + chord * math.sin(mid),
            math.remainder(self.pose.heading + dth, math.tau),
        )
        return self.pose


def _delta32(new: int, old: int) -> int:
    """Counter difference across the 32-bit wrap."""
    return (new - old + 2**31) % 2**32 - 2**31
