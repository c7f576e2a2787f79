"""Map editor (edit_map permission): select, move/rotate, add, delete, resize, maps.

Clicking an obstacle, ball, light or robot puts viser transform controls on it, limited to x/y
moves and rotation about z (``active_axes=(True, True, False)``). When a drag
ends the new pose goes, in mm and radians, through ``WorldFeed.edit``; the
world's new snapshot then reaches every view (the pump redraws on a version
change), so the edit appears live for everyone. The gizmo is in this
browser's scene only.

"Add robot" asks for the arena's centre; a shift-click in the arena asks for that
point. Either way the world puts the robot at the free spot nearest to it.

Everyone in an arena gets the editor's folder; without edit_map its buttons
are disabled and trying anyway (clicking an item) says why, in plain words.
The engine re-checks edit_map on every edit: the page is only a convenience.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Literal

import viser

from common.keys import is_ident
from viewers.web import geometry as geo
from viewers.web.adapters import LabError
from viewers.web.inputs import set_value
from viewers.web.text import escape_md
from viewers.web.world_feed import MapEdit, WorldFeed
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.editor")

NEW_BOX_MM = 150.0
MAX_ARENA_MM = 50_000.0
NO_MAPS = "(no saved maps)"
Kind = Literal["obstacle", "ball", "light", "agent"]
REFUSED = "You may not edit this map: it needs the 'edit_map' permission."


class MapEditor:
    def __init__(self, client: viser.ClientHandle, *, allowed: bool = True) -> None:
        self.client = client
        self.allowed = allowed
        self.view: WorldView | None = None
        self.feed: WorldFeed | None = None
        self.selected: str | None = None
        self.selected_kind: Kind = "obstacle"
        self._gizmo: viser.TransformControlsHandle | None = None
        # The handles are made and dropped from the page's clicks, the view's selection and
        # the bind, on their own threads: two made at once under one name, viser removed one
        # while it was being made (a busy machine's follow-camera test).
        self._gizmo_lock = threading.RLock()
        # Is this robot driven by someone's controller now? (set by the arena's panel)
        self.driven: Callable[[str], bool] = lambda _name: False
        self._click: Callable[[viser.SceneClickEvent], None] | None = None  # shift-click
        gui = client.gui
        off = not allowed
        with gui.add_folder("Map editor", expand_by_default=False):
            self.info = gui.add_markdown(
                "_Click an obstacle, ball, light or robot in the view to move, rotate or "
                "delete it; shift-click in the arena to add a robot there._"
                if allowed
                else f"**{escape_md(REFUSED)}**"
            )
            self.add_box = gui.add_button("Add box", disabled=off)
            self.add_ball = gui.add_button("Add ball", disabled=off)
            self.add_light = gui.add_button("Add light", disabled=off)
            self.add_agent = gui.add_button("Add robot", disabled=off)
            # The type of robot "Add robot" adds: the world's (the robot builder's too).
            self.robot_type = gui.add_dropdown("Robot type", ("khepera",), disabled=off)
            self.delete = gui.add_button("Delete selected", color="red", disabled=True)
            self.width = gui.add_number("Arena width (mm)", 1000.0, min=100.0, step=10.0)
            self.height = gui.add_number("Arena height (mm)", 1000.0, min=100.0, step=10.0)
            self.resize = gui.add_button("Resize arena", disabled=off)
            self.map_name = gui.add_text("Map name", "")
            self.save = gui.add_button("Save map", disabled=off)
            self.maps = gui.add_dropdown("Saved maps", (NO_MAPS,), disabled=off)
            self.list_maps = gui.add_button("List maps", disabled=off)
            self.load = gui.add_button("Load map", disabled=off)
            self.notice = gui.add_markdown("", visible=False)
        self.add_box.on_click(lambda _: self._add("obstacle"))
        self.add_ball.on_click(lambda _: self._add("ball"))
        self.add_light.on_click(lambda _: self._add("light"))
        self.add_agent.on_click(lambda _: self._add("agent"))
        self.delete.on_click(lambda _: self._delete())
        self.resize.on_click(lambda _: self._resize())
        self.save.on_click(lambda _: self._save())
        self.list_maps.on_click(lambda _: self._list())
        self.load.on_click(lambda _: self._load())

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def bind(self, view: WorldView, feed: WorldFeed) -> None:
        self.view, self.feed = view, feed
        view.on_obstacle_click.append(self.select)
        view.on_select.append(self._robot_selected)
        snap = view.snapshot
        if snap is not None:
            set_value(self.width, snap.width)
            set_value(self.height, snap.height)
        if self.allowed:
            try:
                names = tuple(t.name for t in feed.robot_types().types)
            except LabError:
                names = ()
            if names:
                self.robot_type.options = names
        if self.allowed and self._click is None:
            self._click = self._add_at_click
            self.client.scene.on_click(modifier="shift")(self._click)
        if view.selected is not None:  # a robot clicked before the editor was bound to it
            self._robot_selected(view.selected)

    def offer_type(self, name: str) -> None:
        """A robot type just saved (the builder): offered, and chosen, for "Add robot"."""
        options = tuple(self.robot_type.options)
        if name not in options:
            self.robot_type.options = (*options, name)
        set_value(self.robot_type, name)

    def unbind(self) -> None:
        view = self.view
        if view is not None:
            if self.select in view.on_obstacle_click:
                view.on_obstacle_click.remove(self.select)
            if self._robot_selected in view.on_select:
                view.on_select.remove(self._robot_selected)
        if self._click is not None:
            self.client.scene.remove_click_callback(self._click)
            self._click = None
        self._drop_gizmo()
        self.view = self.feed = None

    def _drop_gizmo(self) -> None:
        with self._gizmo_lock:
            if self._gizmo is not None:
                self._gizmo.remove()
                self._gizmo = None
            self.selected = None
            self.delete.disabled = True

    def _find(self, ident: str) -> tuple[Kind, float, float, float] | None:
        feed = self.feed
        if feed is None:
            return None
        snap = feed.snapshot()
        for ob in snap.obstacles:
            if ob.ident == ident:
                return "obstacle", ob.x, ob.y, ob.angle
        frame = feed.latest()
        for i, ball in enumerate(snap.balls):
            if ball.ident == ident:
                if frame is not None and i < len(frame.ball_xy):
                    return "ball", float(frame.ball_xy[i, 0]), float(frame.ball_xy[i, 1]), 0.0
                return "ball", ball.x, ball.y, 0.0
        for light in snap.lights:
            if light.ident == ident:
                return "light", light.x, light.y, 0.0
        if ident in snap.robots and frame is not None:
            i = snap.robots.index(ident)
            if i < len(frame.poses):
                x, y, theta = (float(v) for v in frame.poses[i])
                return "agent", x, y, theta
        return None

    def _robot_selected(self, index: int | None) -> None:
        view = self.view
        name = view.selected_name if view is not None else None
        if name is not None and self.allowed and not self.driven(name):
            self.select(name)
            return
        with self._gizmo_lock:
            if self._gizmo is not None and self.selected_kind == "agent":
                self._drop_gizmo()  # selecting another robot (or none) takes the handles away

    def select(self, ident: str) -> None:
        if not self.allowed:
            self.say_notice(REFUSED)
            return
        found = self._find(ident)
        if found is None:
            return
        kind, x, y, angle = found
        with self._gizmo_lock:
            self._drop_gizmo()
            self.selected, self.selected_kind = ident, kind
            self.delete.disabled = False
            self.info.content = (
                f"Selected **{escape_md(ident)}** ({kind}): drag the arrows or the ring."
            )
            gizmo = self.client.scene.add_transform_controls(
                "/editor/gizmo",
                scale=0.25,
                active_axes=(True, True, False),  # x/y moves, rotation about z only
                disable_sliders=True,
                position=(x * geo.MM, y * geo.MM, 0.04),
                wxyz=tuple(geo.yaw_to_wxyz(angle)),
            )
            gizmo.on_update(self._moved)
            self._gizmo = gizmo

    def _moved(self, event: viser.TransformControlsEvent) -> None:
        if getattr(event, "phase", "end") != "end":
            return  # send one edit per drag, not one per mouse move
        gizmo, feed, ident = self._gizmo, self.feed, self.selected
        if gizmo is None or feed is None or ident is None:
            return
        x, y = geo.viser_to_world(float(gizmo.position[0]), float(gizmo.position[1]))
        angle = geo.wxyz_to_yaw(gizmo.wxyz)
        self._send(feed, MapEdit("move", self.selected_kind, ident, x=x, y=y, angle=angle))

    def _ready(self) -> WorldFeed | None:
        if not self.allowed:
            self.say_notice(REFUSED)
            return None
        if self.feed is None:
            self.say_notice("Press 'Show this arena' first.")
        return self.feed

    def _add(self, kind: Kind) -> None:
        feed = self._ready()
        if feed is None:
            return
        snap = feed.snapshot()
        x, y = snap.width / 2, snap.height / 2
        robot_type = str(self.robot_type.value)
        edit = MapEdit("add", kind, x=x, y=y, w=NEW_BOX_MM, h=NEW_BOX_MM, robot_type=robot_type)
        self._send(feed, edit)

    def _add_at_click(self, event: viser.SceneClickEvent) -> None:
        """A shift-click in the arena: a robot of the chosen type asked for there."""
        feed = self._ready()
        at = _floor_point(event.ray_origin, event.ray_direction)
        if feed is None or at is None:
            return
        robot_type = str(self.robot_type.value)
        self._send(feed, MapEdit("add", "agent", x=at[0], y=at[1], robot_type=robot_type))

    def _delete(self) -> None:
        feed = self._ready()
        if feed is None or self.selected is None:
            return
        if self._send(feed, MapEdit("delete", self.selected_kind, self.selected)):
            self._drop_gizmo()

    def _resize(self) -> None:
        feed = self._ready()
        if feed is None:
            return
        w, h = float(self.width.value), float(self.height.value)
        if not (100.0 <= w <= MAX_ARENA_MM and 100.0 <= h <= MAX_ARENA_MM):
            self.say_notice(f"An arena is 100 to {MAX_ARENA_MM:.0f} mm on each side.")
            return
        self._send(feed, MapEdit("resize", "arena", w=w, h=h))

    def _save(self) -> None:
        feed = self._ready()
        name = self.map_name.value.strip()
        if feed is None:
            return
        if not is_ident(name):
            self.say_notice("Name the map: letters, digits, '_', '-' or '.'.")
            return
        self._map_call(lambda: feed.save_map(name))

    def _list(self) -> None:
        feed = self._ready()
        if feed is None:
            return
        try:
            names = feed.maps()
        except LabError as exc:
            self.say_notice(f"Could not list maps: {exc}")
            return
        self.maps.options = tuple(names) or (NO_MAPS,)
        self.notice.visible = False

    def _load(self) -> None:
        feed = self._ready()
        name = self.maps.value
        if feed is None:
            return
        if name == NO_MAPS:
            self.say_notice("Press 'List maps' and choose one first.")
            return
        self._drop_gizmo()
        self._map_call(lambda: feed.load_map(name))

    def _map_call(self, call: Callable[[], str]) -> None:
        try:
            said = call()
        except LabError as exc:
            self.say_notice(f"Refused: {exc}")
            return
        self.say_notice(said.capitalize() + ".")

    def _send(self, feed: WorldFeed, edit: MapEdit) -> bool:
        try:
            feed.edit(edit)
        except LabError as exc:
            self.say_notice(f"Edit refused: {exc}")
            return False
        self.notice.visible = False
        return True


def _floor_point(
    origin: tuple[float, float, float], direction: tuple[float, float, float]
) -> tuple[float, float] | None:
    """Where a click's ray meets the arena's floor (mm), or None if it never does."""
    ox, oy, oz = origin
    dx, dy, dz = direction
    if abs(dz) < 1e-9 or -oz / dz < 0:
        return None
    t = -oz / dz
    return geo.viser_to_world(ox + t * dx, oy + t * dy)
