"""A world's frame as every view draws it, converted once, and how often a browser gets one.

The pump converts each world's newest frame once per tick (:meth:`PreparedFrame.of`:
poses to viser's positions and orientations, the bodies' colours from the gripper,
the heading arrows' from the LEDs) and hands the same arrays to every view watching
it; :func:`frames_every` keeps a swarm's frames within a browser's byte budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from viewers.web import geometry as geo
from viewers.web.world_feed import SceneFrame

# Gripper state 0 open/none, 1 closed, 2 holding: the robot's body colour says which.
# OFFLINE (3) is the feed's own mark for a real robot the bridge cannot reach: grey.
OFFLINE = 3
GRIPPER_COLOURS = np.array(
    [[70, 130, 220], [230, 150, 40], [40, 170, 80], [160, 160, 160]], np.uint8
)
# The heading arrow on each robot: dark on every body colour; red while an LED is lit.
HEADING_DARK, HEADING_LIT = (20, 20, 25), (230, 0, 0)
HEADING_COLOURS = np.array([HEADING_DARK, HEADING_LIT], np.uint8)
# Level of detail: arrows double what each frame sends a browser (a second pair of
# arrays); past this many robots a heading is a few pixels anyway, so a swarm is
# drawn as bodies alone and a browser's bandwidth stays what it was.
HEADINGS_UP_TO = 300
# Past HEADINGS_UP_TO a robot is a plain disc sent as its position alone.
SWARM_BYTES_PER_ROBOT = 12
FULL_BYTES_PER_ROBOT = 2 * 28  # bodies and arrows: positions and orientations each
# What one browser is sent per second at most for the robots, whatever their number: a
# frame that would exceed it at the pump's rate goes out every k-th tick instead
# (10,000 robots at 25 Hz would be 3 MB/s; they get 8.3 frames a second, 1 MB/s). It is
# about what 1,000 robots cost when every frame went out (0.7 MB/s), so a student's
# link that showed those shows any swarm.
ROBOT_BYTES_PER_S = 1_000_000


def frames_every(robots: int, rate: float) -> int:
    """Send a world of ``robots`` every how many pump ticks (1: every tick) at ``rate`` Hz."""
    per_robot = SWARM_BYTES_PER_ROBOT if robots > HEADINGS_UP_TO else FULL_BYTES_PER_ROBOT
    return max(1, math.ceil(robots * per_robot * rate / ROBOT_BYTES_PER_S))


@dataclass(frozen=True)
class PreparedFrame:
    """A frame converted for viser once, shared by every view of the world."""

    frame: SceneFrame
    positions: npt.NDArray[np.float32]
    wxyzs: npt.NDArray[np.float32]
    colours: npt.NDArray[np.uint8]  # bodies: gripper state
    gripper_key: bytes  # colours change rarely: views compare this before resending
    heading_colours: npt.NDArray[np.uint8]  # heading arrows: any LED lit
    led_key: bytes

    def every(self, rate: float) -> int:
        return frames_every(len(self.positions), rate)

    @staticmethod
    def of(frame: SceneFrame) -> PreparedFrame:
        positions, wxyzs = geo.poses_to_viser(frame.poses)
        state = np.clip(frame.gripper, 0, len(GRIPPER_COLOURS) - 1)
        n = len(frame.poses)
        lit = (frame.leds != 0) if len(frame.leds) == n else np.zeros(n, np.bool_)
        lit &= state != OFFLINE  # an unreachable robot's LEDs are not known
        return PreparedFrame(
            frame,
            positions,
            wxyzs,
            GRIPPER_COLOURS[state],
            state.tobytes(),
            HEADING_COLOURS[lit.astype(np.uint8)],
            lit.tobytes(),
        )
