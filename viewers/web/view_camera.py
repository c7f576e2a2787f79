"""Where one browser's camera looks: the whole arena, fitted again when the canvas
changes shape, or the selected robot, followed.

A part of the world view (world_view.py): the view says what is drawn, this says
where the camera is. It moves the camera only while it is where it put it: once
the person orbits or zooms, the camera is theirs.
"""

from __future__ import annotations

import viser

from viewers.web import geometry as geo
from viewers.web.world_feed import SceneLayout

Position = tuple[float, float, float]


class ArenaCamera:
    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        # Where the camera was aimed to fit the arena, and for which canvas aspect.
        self._fitted: tuple[Position, float] | None = None

    def aim(self, snap: SceneLayout) -> None:
        """Look straight down at the whole arena, fitted to the canvas the browser reported."""
        cam = self.client.camera
        cam.fov = geo.CAMERA_FOV
        cam.up_direction = (0.0, 1.0, 0.0)  # screen-up is world +y
        try:  # the canvas the browser reported (the panel docked beside it takes the rest)
            aspect = geo.fit_aspect(float(cam.aspect))
        except AssertionError:  # not reported yet
            aspect = geo.ASSUMED_ASPECT
        self._aim(snap, aspect)

    def _aim(self, snap: SceneLayout, aspect: float) -> None:
        cx, cy = snap.width * geo.MM / 2, snap.height * geo.MM / 2
        position = (cx, cy, geo.camera_height(snap.width, snap.height, aspect))
        cam = self.client.camera
        cam.position = position
        cam.look_at = (cx, cy, 0.0)
        self._fitted = (position, aspect)

    def refit(self, snap: SceneLayout) -> bool:
        """Aim again for a canvas the panel's width changed (dragged wider or narrower), as
        long as the person has not moved the camera since it was aimed; True if it was."""
        fitted = self._fitted
        if fitted is None:
            return False
        cam = self.client.camera
        try:
            aspect = geo.fit_aspect(float(cam.aspect))
            position = tuple(float(v) for v in cam.position)
        except AssertionError:  # not reported yet
            return False
        where, aimed = fitted
        if max(abs(a - b) for a, b in zip(position, where, strict=True)) > 1e-3:
            # Moved by hand (theirs, left alone), or a report from before the aim that
            # a busy machine delivered late (the next one says where it is).
            return False
        if abs(aspect - aimed) <= 0.02 * aimed:
            return False
        self._aim(snap, aspect)
        return True

    def follow(self, x: float, y: float) -> bool:
        """Centre on (x, y) in viser metres, keeping the height; True if it moved."""
        cam = self.client.camera
        try:
            moved = geo.follow_camera(cam.position, cam.look_at, (x, y))
        except AssertionError:  # the browser has not reported its camera yet
            return False
        if moved is None:
            return False
        with self.client.atomic():
            cam.position, cam.look_at = moved
        return True
