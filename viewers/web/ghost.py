"""The twin's prediction over a live real run: a faint robot a few seconds ahead.

While a controller runs on the selected robot of a real arena, the page draws where
the robot's model says it will be over the next ``HORIZON_S`` seconds if its wheels
keep turning as they do now: a faint disc at the end and the path there, laid over
the camera's video and re-anchored at each new tracked pose. The wheels' speeds are
the robot's odometry, as its sensor sample carries them (``agent/<a>/sensors``, which
the page may read for any robot it shows); the commands a run sends stay between the
runner and the robot. The model is the robot's twin in force, asked of the registry
with the user's own session once per run (in a thread: the pump never waits on a
query); a robot without a twin, or a user the registry does not show twins to, gets
the datasheet Khepera, and the legend under the checkbox says which.

Per frame: nothing unless a new tracked pose came for the selected robot of a live
run, then one closed-form arc of ``PATH_POINTS`` points and two small scene updates.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser

from common.lab_errors import LabError
from common.twin.motion import Drive, ahead
from common.twin.twinfile import Twin
from viewers.web import geometry as geo
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.ghost")

HORIZON_S = 3.0  # how far ahead the ghost is drawn
PATH_POINTS = 16
GHOST_NODE = "/world/ghost"
GHOST_PATH_NODE = "/world/ghost_path"
GHOST_COLOUR = (120, 200, 255)
GHOST_OPACITY = 0.35
DATASHEET = "the datasheet Khepera"


@dataclass(frozen=True)
class Prediction:
    """The model a ghost is drawn by, and the legend's words for it."""

    drive: Drive
    legend: str


def prediction_of(twin: Twin | None, why_not: str = "") -> Prediction:
    if twin is not None:
        return Prediction(twin.drive, f"prediction: {twin.model()}")
    said = f" ({why_not})" if why_not else ""
    return Prediction(Drive(), f"prediction: {DATASHEET}{said}")


def ghost_path(drive: Drive, pose: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """The poses (PATH_POINTS, 3: mm, mm, rad) from ``pose`` to HORIZON_S ahead."""
    times = np.linspace(0.0, HORIZON_S, PATH_POINTS)
    return ahead(drive, np.asarray(pose, np.float64), (float(speeds[0]), float(speeds[1])), times)


class TwinAsker:
    """Each robot's model for the run on it now: asked once per run, off the pump's thread."""

    def __init__(self, twin_of: Callable[[str], Twin | None]) -> None:
        self._twin_of = twin_of
        self._lock = threading.Lock()
        self._known: dict[str, Prediction] = {}
        self._asking: set[str] = set()
        self.asked = 0  # how many times the registry was asked (a run asks once)

    def prediction(self, robot: str) -> Prediction | None:
        """The model, or None while the registry is being asked."""
        with self._lock:
            known = self._known.get(robot)
            if known is not None or robot in self._asking:
                return known
            self._asking.add(robot)
            self.asked += 1
        threading.Thread(target=self._ask, args=(robot,), name=f"twin-{robot}", daemon=True).start()
        return None

    def _ask(self, robot: str) -> None:
        try:
            found = prediction_of(self._twin_of(robot))
        except LabError as exc:  # refused (a student), or no answer: the datasheet's
            log.info("the ghost of %s uses the datasheet: %s", robot, exc)
            found = prediction_of(None, f"{robot}'s twin: {exc}")
        with self._lock:
            self._asking.discard(robot)
            self._known[robot] = found

    def run_ended(self, robot: str) -> None:
        """The next run on ``robot`` asks again (a twin saved meanwhile is then in force)."""
        with self._lock:
            self._known.pop(robot, None)


class Ghost:
    """One browser's ghost of the selected real robot (a tick hook of its world view)."""

    def __init__(
        self,
        gui: viser.GuiApi,
        twin_of: Callable[[str], Twin | None],
        driven: Callable[[str], bool],
    ) -> None:
        self.scene: viser.SceneApi | None = None
        self.view: WorldView | None = None
        self.asker = TwinAsker(twin_of)
        self._driven = driven
        self.checkbox = gui.add_checkbox(
            "Show the twin's prediction",
            True,
            hint=f"While a controller runs on the selected real robot: where its model "
            f"says it will be in {HORIZON_S:.0f} s if its wheels keep their speeds",
        )
        self.legend = gui.add_markdown("", visible=False)
        self.anchored = -1  # the frame (tracked pose) the ghost was last drawn from
        self.drawn_at: np.ndarray | None = None  # the ghost's pose (mm, mm, rad) drawn
        self._live: str | None = None  # the robot whose run the ghost follows
        self._body: viser.CylinderHandle | None = None
        self._path: viser.LineSegmentsHandle | None = None

    def bind(self, view: WorldView) -> None:
        self.view, self.scene = view, view.client.scene
        view.tick_hooks.append(self.tick)

    def unbind(self) -> None:
        view = self.view
        if view is not None and self.tick in view.tick_hooks:
            view.tick_hooks.remove(self.tick)
        self.clear()
        self.view = None

    @property
    def body(self) -> viser.CylinderHandle | None:
        return self._body

    def tick(self) -> None:
        view = self.view
        if view is None:
            return
        snap, drawn, name, feed = view.snapshot, view.drawn, view.selected_name, view.feed
        live = name if snap is not None and snap.real and name and self._driven(name) else None
        if live != self._live:
            if self._live is not None:
                self.asker.run_ended(self._live)
            self._live = live
            self.anchored = -1
        if live is None or feed is None or drawn is None or not self.checkbox.value:
            self.clear()
            return
        if drawn.frame.seq == self.anchored:
            return
        index = view.selected
        readings = feed.sensors(live)
        prediction = self.asker.prediction(live)
        if index is None or index >= len(drawn.frame.poses) or prediction is None:
            return
        if readings is None or len(readings.speeds) < 2:
            return  # no odometry yet: nothing to predict from
        self.anchored = drawn.frame.seq
        self._draw(ghost_path(prediction.drive, drawn.frame.poses[index], readings.speeds))
        if self.legend.content != prediction.legend:
            self.legend.content = prediction.legend
        if not self.legend.visible:
            self.legend.visible = True

    def _draw(self, path: np.ndarray) -> None:
        assert self.scene is not None
        end = path[-1]
        radius = self.view.snapshot.robot_radius if self.view and self.view.snapshot else 27.5
        nose = end[:2] + radius * np.array([np.cos(end[2]), np.sin(end[2])])
        points = np.vstack([path[:, :2], end[:2], nose]).astype(np.float32)
        heading = geo.trail_segments(points[-2:])  # the ghost's nose: which way it faces
        segments = np.concatenate([geo.trail_segments(points[:-2]), heading])
        position = (float(end[0]) * geo.MM, float(end[1]) * geo.MM, 0.012)
        wxyz = geo.yaw_to_wxyz(float(end[2]))
        if self._body is None:
            self._body = self.scene.add_cylinder(
                GHOST_NODE,
                radius=radius * geo.MM,
                height=0.02,
                color=GHOST_COLOUR,
                opacity=GHOST_OPACITY,
                cast_shadow=False,
                receive_shadow=False,
                position=position,
                wxyz=wxyz,
            )
            self._path = self.scene.add_line_segments(
                GHOST_PATH_NODE, segments, colors=GHOST_COLOUR, thickness=0.003
            )
        else:
            self._body.position = position
            self._body.wxyz = wxyz
            if self._path is not None:
                self._path.points = segments
        self.drawn_at = end

    def clear(self) -> None:
        for handle in (self._body, self._path):
            if handle is not None:
                handle.remove()
        self._body = self._path = None
        self.drawn_at = None
        self.anchored = -1
        if self.legend.visible:
            self.legend.visible = False
