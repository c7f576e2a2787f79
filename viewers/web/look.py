"""The selected robot drawn as its robot file's components draw themselves.

One line-segments node in the robot's frame (the type's ``RobotLook`` from the
world's snapshot), moved and turned with the robot each frame: its rim and
heading, IR rays, light sensors, range-finder beams, floor points, bumper
borders. A type written in Python has no look; nothing is drawn for it.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import viser

from viewers.web.world_feed import SceneLayout


class SelectedLook:
    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        self.handle: viser.LineSegmentsHandle | None = None

    def drop(self) -> None:
        if self.handle is not None:
            self.handle.remove()
            self.handle = None

    def show(
        self,
        snap: SceneLayout,
        index: int,
        position: npt.NDArray[np.float32],
        wxyz: npt.NDArray[np.float32],
    ) -> None:
        """Robot ``index`` of ``snap`` at ``position`` (metres) turned by ``wxyz``."""
        if index >= len(snap.robots):
            return
        kind = snap.robot_types.get(snap.robots[index])
        look = snap.looks.get(kind[0]) if kind else None
        if look is None or not len(look[0]):
            return
        if self.handle is None:
            self.handle = self.client.scene.add_line_segments(
                "/world/look", look[0], colors=look[1], thickness=0.0015
            )
        x, y, _ = (float(v) for v in position)
        if tuple(self.handle.position) != (x, y, 0.0):
            self.handle.position = (x, y, 0.0)
        w, qx, qy, qz = (float(v) for v in wxyz)
        if tuple(self.handle.wxyz) != (w, qx, qy, qz):
            self.handle.wxyz = (w, qx, qy, qz)
