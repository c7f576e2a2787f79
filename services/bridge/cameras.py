"""The cameras over a real arena, as the bridge follows them: present or gone, and their clocks.

The arena's cameras are offline when the last one's process is gone (its
presence token leaves: at once, not after a silence), or when none has said
anything for CAMERA_HUNG_S (a hung capture). Not after a short silence: a busy
camera host's frames stall for seconds, and a robot the camera does not see
must stay "not seen", never wander off on odometry. Each camera's stamps are
put on this host's clock (CameraClock). Several cameras may share the arena
(one per half): their sightings are fused (common/tracking/fusion.py), and one
gone while others live puts only the robots it alone saw on odometry.
"""

from __future__ import annotations

import threading

from common.tracking.fusion import CameraClock, PoseFusion

CAMERA_HUNG_S = 10.0  # a camera process present but silent this long: offline
MAX_CAMERAS = 16  # cameras over one arena that are followed (a bad publisher: no more)


class ArenaCameras:
    """Which cameras track this arena, which are alive; each camera's clock."""

    def __init__(self, fusion: PoseFusion) -> None:
        self.fusion = fusion
        self._lock = threading.Lock()
        self._clocks: dict[str, CameraClock] = {}  # the cameras that sent us frames
        self._alive: set[str] = set()  # camera processes present in the realm
        self._left: set[str] = set()  # ... and those whose process has gone

    def presence(self, camera: str, present: bool) -> None:
        """A camera process came or went: one of ours gone, with none left, is offline now."""
        with self._lock:
            if present:
                self._alive.add(camera)
                self._left.discard(camera)
                self.fusion.camera_back(camera)
                return
            self._alive.discard(camera)
            self._left.add(camera)
            while len(self._left) > MAX_CAMERAS:
                self._left.pop()
            ours = set(self._clocks)
            gone = camera in ours and not ours & self._alive
        if camera in ours:
            self.fusion.camera_left(camera)
        if gone:
            self.fusion.camera_gone()

    def frame(
        self, camera: str, captured_at: float, now: float, sent_at: float | None = None
    ) -> float | None:
        """A frame from ``camera`` arrived ``now`` (sent at ``sent_at`` by its clock, if it
        says): its capture time on this clock, or None for a frame still on its way from a
        camera whose process is gone."""
        with self._lock:
            if camera in self._left:
                return None
            clock = self._clocks.pop(camera, None) or CameraClock()
            self._clocks[camera] = clock  # the newest last: the oldest goes first
            while len(self._clocks) > MAX_CAMERAS:
                self._clocks.pop(next(iter(self._clocks)))
        self.fusion.camera_alive(now)
        return clock.local(captured_at, now, sent_at)
