"""The arena camera's wire types: compressed frames, tracked poses, the camera's status.

A frame is one JPEG of the arena as the camera saw it; the tracked poses are the
robots the tracker found in that frame, in arena mm and radians, with the
frame's capture time (wall clock, seconds). Both are published newest-only: a
slow subscriber skips frames, it never queues them.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText

MAX_FRAME_BYTES = 2 * 1024 * 1024  # a 1280x960 JPEG at quality 90 is about 400 KB
MAX_TRACKED = 64  # an arena's marked robots (ArUco 4x4: 46 robot ids)

Pixels = Annotated[int, msgspec.Meta(ge=16, le=4096)]
FrameBytes = Annotated[bytes, msgspec.Meta(max_length=MAX_FRAME_BYTES)]


class CameraFrame(Message, frozen=True):
    """One frame of a camera over a world's arena: as it saw it (``.../image``), or the
    floor rectified to the arena, +y up, 2 mm a pixel (``.../floor``)."""

    world: Ident
    camera: Ident
    seq: NonNegInt
    captured_at: float  # wall clock, seconds
    width: Pixels
    height: Pixels
    encoding: Literal["jpeg"] = "jpeg"
    data: FrameBytes = b""


class TrackedRobot(msgspec.Struct, frozen=True):
    """One robot found in one frame: arena mm and radians."""

    agent: Ident
    x: float
    y: float
    heading: float
    marker: Annotated[int, msgspec.Meta(ge=0, le=1023)]


class TrackedPoses(Message, frozen=True):
    """The robots a camera found in one frame (``world/<w>/tracked``)."""

    world: Ident
    camera: Ident
    seq: NonNegInt
    captured_at: float
    robots: Annotated[list[TrackedRobot], msgspec.Meta(max_length=MAX_TRACKED)] = msgspec.field(
        default_factory=list
    )
    # When the camera sent it, on its clock: the bridge tells the clocks' difference from
    # the network's delay alone, not from the frame's processing too. None: an older camera.
    sent_at: Annotated[float, msgspec.Meta(gt=0.0)] | None = None


class CameraStatus(Message, frozen=True):
    """Whether a camera sees its arena (``world/<w>/camera/<c>/status``)."""

    world: Ident
    camera: Ident
    online: bool
    reason: ShortText = ""  # why it is offline, for the page ("camera offline: ...")
    source: ShortText = ""  # what it captures from, as the operator named it
    fps: Annotated[float, msgspec.Meta(ge=0.0)] = 0.0
    width: NonNegInt = 0
    height: NonNegInt = 0
    tracking: bool = False  # calibrated: tracked poses are published
    at: float = 0.0


__all__ = [
    "MAX_FRAME_BYTES",
    "MAX_TRACKED",
    "CameraFrame",
    "CameraStatus",
    "TrackedPoses",
    "TrackedRobot",
]
