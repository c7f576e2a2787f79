"""One browser's top-down view of a world (everything here draws into ``client.scene``).

Drawn from the world's snapshot (floor, obstacles, balls, lights), then kept
live by :class:`~viewers.web.pump.FramePump`, which hands every watching view
the same :class:`PreparedFrame` (converted once per world per tick). All
robots are two batched meshes, bodies and heading arrows (never a node per
robot): a frame is the same two arrays (positions, orientations) assigned to
both inside ``client.atomic()``, whatever the number of robots (past
HEADINGS_UP_TO robots the arrows are left out and the bodies are plain discs
sent as positions only, and a huge swarm's frames are decimated to a byte
budget: level of detail). Only the
selected robot gets extras (label, trail, IR rays); with few robots every one
is labelled.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import viser

from viewers.web import geometry as geo
from viewers.web.look import SelectedLook
from viewers.web.prepared_frame import (
    GRIPPER_COLOURS,
    HEADING_COLOURS,
    HEADINGS_UP_TO,
    PreparedFrame,
)
from viewers.web.view_camera import ArenaCamera
from viewers.web.viser_fast import set_shared_arrays
from viewers.web.world_feed import SceneFrame, SceneLayout, WorldFeed

log = logging.getLogger("wart.viewer.world")

MAX_ITEM_NODES = 500
LABEL_ALL_UP_TO = 12  # more robots than this: only the selected one is labelled
TRAIL_POINTS = 300
FLOOR_COLOUR = (235, 235, 230)
OBSTACLE_COLOUR = (110, 110, 120)
BALL_COLOUR = (220, 60, 60)
LIGHT_ON, LIGHT_OFF = (255, 220, 40), (150, 150, 150)
# Past HEADINGS_UP_TO a robot is a plain disc: the same from every heading, so a frame
# carries positions alone (12 bytes a robot instead of 28 for the bodies).
# Past POINTS_FROM the discs are one point cloud (round sprites a robot wide) rather
# than a batched mesh: the page then uploads the positions as they come, where viser's
# batched mesh composes a matrix per instance in JavaScript at every frame and keeps
# a picking tree up to date. A click is then found by where it meets the floor.
POINTS_FROM = 2_000


def _disc(
    scene: viser.SceneApi,
    name: str,
    radius_mm: float,
    height: float,
    colour: tuple[int, int, int],
    at_mm: tuple[float, float],
    z: float,
) -> viser.CylinderHandle:
    """A flat cylinder on the floor (a pillar, a ball, a light), casting and taking no
    shadow: its radius and place in arena mm, its height and ``z`` in scene metres."""
    return scene.add_cylinder(
        name,
        radius=radius_mm * geo.MM,
        height=height,
        color=colour,
        position=(at_mm[0] * geo.MM, at_mm[1] * geo.MM, z),
        cast_shadow=False,
        receive_shadow=False,
    )


class WorldView:
    """The arena in one client's 3D canvas; selection and extras are this client's own."""

    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        self.feed: WorldFeed | None = None
        self.snapshot: SceneLayout | None = None
        self.selected: int | None = None
        self.show_rays = False
        self.follow = False  # keep the selected robot centred (the slow tick moves the camera)
        self.last_seq = -1
        self.frames_applied = 0
        self.drawn: PreparedFrame | None = None  # the frame the robots are drawn at now
        self._lock = threading.RLock()  # the pump thread and GUI callbacks both draw
        self._robots: viser.BatchedMeshHandle | viser.PointCloudHandle | None = None
        self._headings: viser.BatchedMeshHandle | None = None
        self._ring: viser.SceneNodeHandle | None = None
        self._labels: dict[int, viser.LabelHandle] = {}
        self._floor_clicks: Callable[[viser.SceneClickEvent], None] | None = None
        self._trail: deque[tuple[float, float]] = deque(maxlen=TRAIL_POINTS)
        self._trail_handle: viser.LineSegmentsHandle | None = None
        self._rays: viser.LineSegmentsHandle | None = None
        # The selected robot's look (its robot file's components), moved with it.
        self._look = SelectedLook(client)
        self.camera = ArenaCamera(client)  # where this browser's camera looks
        self._static: list[viser.SceneNodeHandle] = []
        self._balls: list[viser.SceneNodeHandle] = []
        self._lights: list[viser.CylinderHandle] = []
        self._light_state: bytes = b""
        self._gripper_key: bytes = b""
        self._led_key: bytes = b""
        self._ticks = 0
        self.on_select: list[Callable[[int | None], None]] = []
        self.on_obstacle_click: list[Callable[[str], None]] = []
        self.slow_hooks: list[Callable[[], None]] = []  # run at about 5 Hz by the pump
        self.tick_hooks: list[Callable[[], None]] = []  # every pump tick (25 Hz): cheap ones
        self._setup_scene()

    def _setup_scene(self) -> None:
        scene = self.client.scene
        # Software WebGL (headless Chromium, cheap laptops) renders default lights,
        # environment map and shadows at about 2 fps; flat ambient light at about 25.
        scene.configure_default_lights(enabled=False, cast_shadow=False)
        scene.configure_environment_map(hdri=None)
        scene.add_light_ambient("/light", intensity=2.5)
        scene.set_up_direction("+z")

    # -- what the UI calls

    @property
    def robot_names(self) -> tuple[str, ...]:
        return self.snapshot.robots if self.snapshot else ()

    @property
    def selected_name(self) -> str | None:
        names = self.robot_names
        if self.selected is None or self.selected >= len(names):
            return None
        return names[self.selected]

    def drawn_positions(self) -> npt.NDArray[np.float32] | None:
        """The robots' positions (viser metres) as last assigned to the browser's mesh."""
        with self._lock:
            robots = self._robots
            if robots is None:
                return None
            if isinstance(robots, viser.PointCloudHandle):
                return np.array(robots.points, np.float32)
            return np.array(robots.batched_positions, np.float32)

    def show(self, feed: WorldFeed) -> None:
        """Watch ``feed``: draw its snapshot, aim the camera; frames follow from the pump.

        The world shown already (the page said again which tab is in front, or a
        late answer opened it again) stays as the student left it: the selected
        robot, its trail and the camera."""
        with self._lock:
            if feed is self.feed and self.snapshot is not None:
                return
            self.feed = feed
            self.last_seq = -1
            self.drawn = None
            # Nothing of the world shown before stays drawn: its selected robot's
            # trail, rays and look (a replay's trail, another arena's robot).
            self._drop_selected()
            self.redraw(feed.snapshot())
            snap = self.snapshot
            assert snap is not None
            self.camera.aim(snap)

    def refit(self) -> bool:
        """Fit the arena again to a canvas that changed shape (see ArenaCamera.refit)."""
        with self._lock:
            snap = self.snapshot
            if snap is None or self.follow:
                return False
            return self.camera.refit(snap)

    def hide(self) -> None:
        with self._lock:
            self.feed = None
            self.snapshot = None
            self._clear_all()

    def select(self, index: int | None) -> None:
        with self._lock:
            if index is not None and not 0 <= index < len(self.robot_names):
                index = None
            if index == self.selected:
                return
            self._drop_selected()
            self.selected = index
            self._sync_labels()
        for callback in list(self.on_select):
            callback(index)

    def _drop_extras(self) -> None:
        """The selected robot's trail, rays and look: another robot, or none, is selected."""
        self._trail.clear()
        for extra in (self._trail_handle, self._rays):
            if extra is not None:
                extra.remove()
        self._trail_handle = self._rays = None
        self._drop_look()

    # -- drawing

    def _drop_selected(self) -> None:
        """No robot selected, and nothing drawn for the one that was."""
        self.selected = None
        self._drop_extras()

    def _clear_all(self) -> None:
        for handle in [*self._static, *self._balls, *self._lights, *self._labels.values()]:
            handle.remove()
        self._static, self._balls, self._lights, self._labels = [], [], [], {}
        for extra in (self._robots, self._headings, self._ring, self._trail_handle, self._rays):
            if extra is not None:
                extra.remove()
        self._robots = self._headings = self._ring = self._trail_handle = self._rays = None
        self._drop_look()
        self._gripper_key = self._led_key = b""
        self._light_state = b""

    def redraw(self, snap: SceneLayout) -> None:
        """Draw (or redraw after an edit) everything that comes from the snapshot.

        The selected robot stays selected by its name (its index moves when a robot
        before it is removed); once it is removed nothing is, and listeners are told.
        """
        with self._lock:
            name = self.selected_name
            now = snap.robots.index(name) if name in snap.robots else None
            reselected = now != self.selected
            if reselected:
                self.selected = now
                if now is None:
                    self._drop_extras()
            old = self.snapshot
            robots_changed = old is None or (old.robots, old.offline, old.robot_radii) != (
                snap.robots,
                snap.offline,
                snap.robot_radii,
            )
            self.snapshot = snap
            scene = self.client.scene
            for handle in [*self._static, *self._balls, *self._lights]:
                handle.remove()
            self._static, self._balls, self._lights = [], [], []
            self._light_state = b""
            floor = scene.add_box(
                "/world/floor",
                color=FLOOR_COLOUR,
                dimensions=(snap.width * geo.MM, snap.height * geo.MM, 0.002),
                position=(snap.width * geo.MM / 2, snap.height * geo.MM / 2, -0.002),
                cast_shadow=False,
                receive_shadow=False,
            )
            self._static.append(floor)
            for i, (points, width, colour) in enumerate(snap.floor_lines[:MAX_ITEM_NODES]):
                line = geo.floor_line_segments(points)
                if len(line):
                    self._static.append(
                        scene.add_line_segments(
                            f"/world/floor_lines/{i}",
                            line,
                            colors=geo.hex_rgb(colour),
                            thickness=width * geo.MM,
                        )
                    )
            # Each item is its own scene node (about 50 us per change): past this many of
            # a kind a map would need a batched mesh; the rest are not drawn.
            shown = MAX_ITEM_NODES
            for ob in snap.obstacles[:shown]:
                node: viser.SceneNodeHandle
                if ob.round:  # pillars: discs from above
                    node = _disc(
                        scene, f"/world/obstacles/{ob.ident}", ob.w / 2, 0.03, OBSTACLE_COLOUR,
                        (ob.x, ob.y), 0.015,
                    )  # fmt: skip
                else:
                    node = scene.add_box(
                        f"/world/obstacles/{ob.ident}",
                        color=OBSTACLE_COLOUR,
                        dimensions=(ob.w * geo.MM, ob.h * geo.MM, 0.03),
                        position=(ob.x * geo.MM, ob.y * geo.MM, 0.015),
                        wxyz=tuple(geo.yaw_to_wxyz(ob.angle)),
                        cast_shadow=False,
                        receive_shadow=False,
                    )
                node.on_click(self._obstacle_clicked(ob.ident))
                self._static.append(node)
            for ball in snap.balls[:shown]:
                node = _disc(
                    scene, f"/world/balls/{ball.ident}", ball.r, 0.02, BALL_COLOUR,
                    (ball.x, ball.y), 0.01,
                )  # fmt: skip
                node.on_click(self._obstacle_clicked(ball.ident))
                self._balls.append(node)
            for light in snap.lights[:shown]:
                node = _disc(
                    scene, f"/world/lights/{light.ident}", 30.0, 0.005,
                    LIGHT_ON if light.on else LIGHT_OFF, (light.x, light.y), 0.003,
                )  # fmt: skip
                node.on_click(self._obstacle_clicked(light.ident))
                self._lights.append(node)
            if robots_changed or self._robots is None:
                for label in self._labels.values():  # names or online states changed
                    label.remove()
                self._labels.clear()
                self._draw_robots(snap)
        if reselected:
            for callback in list(self.on_select):
                callback(now)

    def _obstacle_clicked(self, ident: str) -> Callable[[object], None]:
        def clicked(_event: object) -> None:
            for callback in list(self.on_obstacle_click):
                callback(ident)

        return clicked

    def _draw_robots(self, snap: SceneLayout) -> None:
        for old in (self._robots, self._headings):
            if old is not None:
                old.remove()
        radius = snap.robot_radius * geo.MM
        n = len(snap.robots)
        swarm = n > HEADINGS_UP_TO
        # Robots of several sizes (robot files): one mesh, each instance scaled to its radius.
        scales = (
            np.asarray(snap.robot_radii, np.float32) / np.float32(snap.robot_radius)
            if len(snap.robot_radii) == n and n
            else None
        )
        if n > POINTS_FROM:
            self._robots = self.client.scene.add_point_cloud(
                "/world/robots",
                points=np.zeros((n, 3), np.float32),
                colors=np.tile(GRIPPER_COLOURS[0], (n, 1)),
                point_size=2 * radius,
                point_shape="circle",
                precision="float32",
                point_shading="flat",
            )
            if self._floor_clicks is None:
                self._floor_clicks = self.client.scene.on_click()(self._floor_clicked)
        else:
            self._robots = self._add_batch(
                "/world/robots",
                geo.swarm_disc_mesh(radius) if swarm else geo.robot_mesh(radius),
                n,
                GRIPPER_COLOURS[0],
                scales,
            )
        # The arrow lies on top of the body: a click on it selects the robot too.
        self._headings = (
            self._add_batch(
                "/world/headings", geo.heading_mesh(radius), n, HEADING_COLOURS[0], scales
            )
            if n <= HEADINGS_UP_TO
            else None
        )
        self._gripper_key = self._led_key = b""
        self.drawn = None  # new meshes start at the origin: the next frame must place them
        if self._ring is not None:
            self._ring.remove()
        self._ring = self.client.scene.add_cylinder(
            "/world/selected",
            radius=snap.robot_radius * geo.MM * 1.5,
            height=0.004,
            color=(255, 60, 200),
            position=(0.0, 0.0, 0.0),
            visible=False,
            cast_shadow=False,
            receive_shadow=False,
        )
        self._sync_labels()

    def _add_batch(
        self,
        name: str,
        mesh: tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32]],
        n: int,
        colour: npt.NDArray[np.uint8],
        scales: npt.NDArray[np.float32] | None = None,
    ) -> viser.BatchedMeshHandle:
        """One batched mesh with an instance per robot (placed by the first frame)."""
        vertices, faces = mesh
        handle = self.client.scene.add_batched_meshes_simple(
            name,
            vertices=vertices,
            faces=faces,
            batched_wxyzs=np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
            batched_positions=np.zeros((n, 3), np.float32),
            batched_scales=scales,
            batched_colors=np.tile(colour, (n, 1)),
            lod="off",  # meshes of a few dozen triangles need no simplification
            cast_shadow=False,
            receive_shadow=False,
            flat_shading=True,
        )
        handle.on_click(self._robot_clicked)
        return handle

    def _robot_clicked(self, event: viser.SceneNodePointerEvent[viser.BatchedMeshHandle]) -> None:
        self.select(event.instance_index)

    def _floor_clicked(self, event: viser.SceneClickEvent) -> None:
        """A click on a swarm drawn as points: select the robot under it, if any."""
        with self._lock:
            robots, drawn, snap = self._robots, self.drawn, self.snapshot
            if not isinstance(robots, viser.PointCloudHandle) or drawn is None or snap is None:
                return
            index = geo.robot_at(
                event.ray_origin, event.ray_direction, drawn.positions, snap.robot_radius * geo.MM
            )
        if index is not None:
            self.select(index)

    def _sync_labels(self) -> None:
        """Labels: every robot when few, else only the selected one."""
        names = self.robot_names
        wanted = set(range(len(names))) if len(names) <= LABEL_ALL_UP_TO else set()
        if self.selected is not None:
            wanted.add(self.selected)
        for index in set(self._labels) - wanted:
            self._labels.pop(index).remove()
        for index in wanted - set(self._labels):
            offline = self.snapshot is not None and names[index] in self.snapshot.offline
            self._labels[index] = self.client.scene.add_label(
                f"/world/labels/{index}",
                f"{names[index]} (offline)" if offline else names[index],
                anchor="bottom-center",
            )

    def apply(self, prepared: PreparedFrame) -> None:
        """Show a frame (called by the pump thread, paced)."""
        with self._lock:
            robots, headings = self._robots, self._headings
            snap = self.snapshot
            if robots is None or snap is None or prepared.frame.seq == self.last_seq:
                return
            frame = prepared.frame
            if len(prepared.positions) != len(snap.robots):
                return  # frame from before a robot was added or removed: wait for the next
            self._ticks += 1
            with self.client.atomic():
                # The prepared arrays are shared by every view (viser_fast: no copies).
                moved = self.drawn is None or not np.array_equal(
                    self.drawn.positions, prepared.positions
                )
                turned = self.drawn is None or not np.array_equal(self.drawn.wxyzs, prepared.wxyzs)
                # A still world sends nothing (as viser's own setter did); a swarm of
                # discs (no arrows) sends no orientations.
                points = isinstance(robots, viser.PointCloudHandle)
                position_prop = "points" if points else "batched_positions"
                arrays = {position_prop: prepared.positions} if moved else {}
                if turned and headings is not None:
                    arrays["batched_wxyzs"] = prepared.wxyzs
                if arrays:
                    set_shared_arrays(robots, arrays)
                    if headings is not None:
                        set_shared_arrays(headings, arrays)
                if prepared.gripper_key != self._gripper_key:
                    if isinstance(robots, viser.PointCloudHandle):
                        robots.colors = prepared.colours
                    else:
                        robots.batched_colors = prepared.colours
                    self._gripper_key = prepared.gripper_key
                if headings is not None and prepared.led_key != self._led_key:
                    headings.batched_colors = prepared.heading_colours
                    self._led_key = prepared.led_key
                for index, label in self._labels.items():
                    x, y, _ = prepared.positions[index]
                    label.position = (float(x), float(y), 0.05)
                self._apply_objects(frame)
                self._apply_selected(prepared)
            self.last_seq = frame.seq
            self.frames_applied += 1
            self.drawn = prepared

    def _apply_objects(self, frame: SceneFrame) -> None:
        for handle, (x, y) in zip(self._balls, frame.ball_xy, strict=False):
            position = (float(x) * geo.MM, float(y) * geo.MM, 0.01)
            if tuple(handle.position) != position:
                handle.position = position
        state = frame.lights_on.tobytes()
        if state != self._light_state:
            for handle, on in zip(self._lights, frame.lights_on, strict=False):
                handle.color = LIGHT_ON if on else LIGHT_OFF
            self._light_state = state

    def _drop_look(self) -> None:
        self._look.drop()

    def _apply_selected(self, prepared: PreparedFrame) -> None:
        ring = self._ring
        index = self.selected
        if ring is None:
            return
        if index is None or index >= len(prepared.positions):
            if ring.visible:
                ring.visible = False
            return
        x, y, _ = prepared.positions[index]
        ring.position = (float(x), float(y), 0.001)
        if not ring.visible:
            ring.visible = True
        if len(prepared.wxyzs) > index and self.snapshot is not None:
            self._look.show(self.snapshot, index, prepared.positions[index], prepared.wxyzs[index])
        pose = prepared.frame.poses[index]
        self._trail.append((float(pose[0]), float(pose[1])))
        if self._ticks % 5 == 0:  # the trail grows slowly: 5 Hz is plenty
            segments = geo.trail_segments(np.asarray(self._trail, np.float32))
            if len(segments):
                if self._trail_handle is None:
                    self._trail_handle = self.client.scene.add_line_segments(
                        "/world/trail", segments, colors=(255, 60, 200), thickness=0.004
                    )
                else:
                    self._trail_handle.points = segments
        if self.show_rays and self.feed is not None and self.selected_name is not None:
            sample = self.feed.sensors(self.selected_name)
            if sample is not None:
                radius = self.snapshot.robot_radius if self.snapshot else 27.5
                rays = geo.ir_segments(pose, sample.ir, radius)
                colours = geo.ir_colours(sample.ir)
                if self._rays is None:
                    self._rays = self.client.scene.add_line_segments(
                        "/world/rays", rays, colors=colours, thickness=0.003
                    )
                else:
                    self._rays.points = rays
                    self._rays.colors = colours
        elif self._rays is not None:
            self._rays.remove()
            self._rays = None

    def follow_selected(self) -> bool:
        """Centre this browser's camera on the selected robot if following (True: moved).

        Called at the pump's slow tick (5 Hz), never per frame: the camera is one
        message per browser, and a student can still zoom (the height is kept).
        """
        with self._lock:
            drawn, index = self.drawn, self.selected
            if not self.follow or drawn is None or index is None:
                return False
            if index >= len(drawn.positions):
                return False
            x, y = drawn.positions[index, :2]
            return self.camera.follow(float(x), float(y))

    def slow_tick(self) -> None:
        self.follow_selected()
        self.refit()
        for hook in list(self.slow_hooks):
            hook()
