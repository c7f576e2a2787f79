"""Map editor skeleton (edit_map permission): select, move/rotate, add, delete.

Clicking an obstacle puts viser transform controls on it, limited to x/y
moves and rotation about z (``active_axes=(True, True, False)``). When a drag
ends the new pose goes, in mm and radians, through ``WorldFeed.edit``; the
world's new snapshot then reaches every view (the pump redraws on a version
change), so the edit appears live for everyone. The gizmo is in this
browser's scene only.
"""

from __future__ import annotations

import logging

import viser

from viewers.web import geometry as geo
from viewers.web.adapters import LabError, MapEdit, WorldFeed
from viewers.web.text import escape_md
from viewers.web.world_view import WorldView

log = logging.getLogger("wart.viewer.editor")

NEW_BOX_MM = 150.0


class MapEditor:
    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        self.view: WorldView | None = None
        self.feed: WorldFeed | None = None
        self.selected: str | None = None
        self._gizmo: viser.TransformControlsHandle | None = None
        gui = client.gui
        with gui.add_folder("Map editor", expand_by_default=False):
            self.info = gui.add_markdown("_Click an obstacle in the view to move or rotate it._")
            self.add_box = gui.add_button("Add box")
            self.add_ball = gui.add_button("Add ball")
            self.add_light = gui.add_button("Add light")
            self.delete = gui.add_button("Delete selected", color="red", disabled=True)
            self.notice = gui.add_markdown("", visible=False)
        self.add_box.on_click(lambda _: self._add("obstacle"))
        self.add_ball.on_click(lambda _: self._add("ball"))
        self.add_light.on_click(lambda _: self._add("light"))
        self.delete.on_click(lambda _: self._delete())

    def say_notice(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def bind(self, view: WorldView, feed: WorldFeed) -> None:
        self.view, self.feed = view, feed
        view.on_obstacle_click.append(self.select)

    def unbind(self) -> None:
        if self.view is not None and self.select in self.view.on_obstacle_click:
            self.view.on_obstacle_click.remove(self.select)
        self._drop_gizmo()
        self.view = self.feed = None

    def _drop_gizmo(self) -> None:
        if self._gizmo is not None:
            self._gizmo.remove()
            self._gizmo = None
        self.selected = None
        self.delete.disabled = True

    def select(self, ident: str) -> None:
        feed = self.feed
        if feed is None:
            return
        found = [o for o in feed.snapshot().obstacles if o.ident == ident]
        if not found:
            return
        ob = found[0]
        self._drop_gizmo()
        self.selected = ident
        self.delete.disabled = False
        self.info.content = f"Selected **{escape_md(ident)}**: drag the arrows or the ring."
        gizmo = self.client.scene.add_transform_controls(
            "/editor/gizmo",
            scale=0.25,
            active_axes=(True, True, False),  # x/y moves, rotation about z only
            disable_sliders=True,
            position=(ob.x * geo.MM, ob.y * geo.MM, 0.04),
            wxyz=tuple(geo.yaw_to_wxyz(ob.angle)),
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
        self._send(
            feed, MapEdit("move", "obstacle", ident, x=x, y=y, angle=geo.wxyz_to_yaw(gizmo.wxyz))
        )

    def _add(self, kind: str) -> None:
        feed = self.feed
        if feed is None:
            self.say_notice("Press 'Show this arena' first.")
            return
        snap = feed.snapshot()
        x, y = snap.width / 2, snap.height / 2
        edit = MapEdit("add", kind, x=x, y=y, w=NEW_BOX_MM, h=NEW_BOX_MM)  # type: ignore[arg-type]
        self._send(feed, edit)

    def _delete(self) -> None:
        if self.feed is None or self.selected is None:
            return
        self._send(self.feed, MapEdit("delete", "obstacle", self.selected))
        self._drop_gizmo()

    def _send(self, feed: WorldFeed, edit: MapEdit) -> None:
        try:
            feed.edit(edit)
        except LabError as exc:
            self.say_notice(f"Edit refused: {exc}")
            return
        self.notice.visible = False
