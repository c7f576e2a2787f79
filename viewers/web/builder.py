"""The robot builder: compose a robot type from parts in the page, save it to the lab.

Start from a type the world has (its file, as the world gives it), add
components of any type the lab has (a table with each parameter at its
schema's default, units and meaning as comments), edit the numbers, Check it
(the same validation the world runs: every problem with its line and field),
and save it to the lab (``edit_map``, common/robots/, docs/ROBOTS.md). The map
editor's "Robot type" then puts robots of it into the arena. The file is data:
the world validates it again and never executes it.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import viser

from common.robots import registry
from common.robots.robotfile import RobotFileError, parse
from common.robots.schema import show_value
from common.sim2d.specs import AgentTypeSpec
from viewers.web import geometry as geo
from viewers.web.adapters import LabError
from viewers.web.inputs import set_value
from viewers.web.text import escape_md
from viewers.web.world_feed import WorldFeed

REFUSED = "Building robot types needs the 'edit_map' permission."
# The drawing's colours by component role: the body dark, IR rays red, light sensors
# amber, batched sensors (beams, floor points, bumper borders) blue.
ROLE_COLOURS = {
    "body": (40, 40, 40),
    "proximity": (220, 50, 50),
    "ambient": (230, 160, 0),
    "sensor": (30, 110, 230),
}
PREVIEW_Z = 0.03  # metres: above the floor and the robots


def preview_segments(
    spec: AgentTypeSpec, x_mm: float, y_mm: float
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """The composed robot as line segments (metres, viser) at (x, y) facing +x, and colours:
    each component draws itself (ComponentType.preview, robot frame)."""
    segs: list[tuple[float, float, float, float]] = []
    colours: list[tuple[int, int, int]] = []
    components = registry.default().components
    for info in spec.components:
        component = components.get(info.type)
        if component is None:
            continue
        drawn = component.preview(info.values)
        segs += drawn
        colours += [ROLE_COLOURS.get(info.role, (90, 90, 90))] * len(drawn)
    out = np.zeros((len(segs), 2, 3), np.float32)
    if segs:
        a = np.asarray(segs, np.float64)
        out[:, 0, 0], out[:, 0, 1] = (x_mm + a[:, 0]) * geo.MM, (y_mm + a[:, 1]) * geo.MM
        out[:, 1, 0], out[:, 1, 1] = (x_mm + a[:, 2]) * geo.MM, (y_mm + a[:, 3]) * geo.MM
        out[:, :, 2] = PREVIEW_Z
    rgb = np.repeat(np.asarray(colours, np.uint8).reshape(-1, 1, 3), 2, axis=1)
    return out, rgb


NO_TYPES = "(press 'List types')"


def component_snippet(type_name: str, taken: str) -> str:
    """A ``[components.<name>]`` table for a component type, every parameter at its default."""
    component = registry.default().components[type_name]
    base = type_name.split("_")[0]
    name, i = base, 2
    while f"[components.{name}]" in taken:
        name, i = f"{base}{i}", i + 1
    lines = ["", f"# {component.doc}", f"[components.{name}]", f'type = "{type_name}"']
    for p in component.params:
        unit = f" [{p.unit}]" if p.unit else ""
        if p.required:
            lines.append(f"# {p.name} = ...  (required{unit}: {p.doc})")
        else:
            lines.append(f"{p.name} = {show_value(p.default)}  # {p.doc}{unit}")
    return "\n".join(lines) + "\n"


class RobotBuilder:
    """The builder's folder in an arena's panel; bound to the arena's world when it is shown."""

    def __init__(self, client: viser.ClientHandle, *, allowed: bool) -> None:
        self.client = client
        self.allowed = allowed
        self.feed: WorldFeed | None = None
        self._preview: viser.LineSegmentsHandle | None = None
        self.world_kinds: tuple[str, ...] = ()  # the world's component types, once listed
        # Called with the type's name after a save (the map editor offers it).
        self.on_saved: list[Callable[[str], None]] = []
        gui = client.gui
        off = not allowed
        with gui.add_folder("Robot builder", expand_by_default=False):
            self.info = gui.add_markdown(
                "_Start from a type, add components, set their numbers, Check, save._"
                if allowed
                else f"**{escape_md(REFUSED)}**"
            )
            self.list_types = gui.add_button("List types", disabled=off)
            self.start_from = gui.add_dropdown("Start from", (NO_TYPES,), disabled=off)
            self.open = gui.add_button("Open type", disabled=off)
            kinds = tuple(sorted(registry.default().components))
            self.kind = gui.add_dropdown("Component", kinds, disabled=off)
            self.add = gui.add_button("Add component", disabled=off)
            self.text = gui.add_text("Robot file", "", multiline=True, disabled=off)
            self.check = gui.add_button("Check robot file", disabled=off)
            self.save = gui.add_button("Save type to the lab", color="green", disabled=off)
            self.notice = gui.add_markdown("", visible=False)
        self.list_types.on_click(lambda _: self._list())
        self.open.on_click(lambda _: self._open())
        self.add.on_click(lambda _: self._add())
        self.check.on_click(lambda _: self._check())
        self.save.on_click(lambda _: self._save())

    def bind(self, feed: WorldFeed) -> None:
        self.feed = feed

    def unbind(self) -> None:
        self.feed = None
        self.hide_preview()

    def hide_preview(self) -> None:
        if self._preview is not None:
            self._preview.remove()
            self._preview = None

    def show_preview(self, spec: AgentTypeSpec) -> bool:
        """Draw the checked robot at the arena's centre: body, heading, rays, beams, points."""
        feed = self.feed
        if feed is None:
            return False
        try:
            snap = feed.snapshot()
        except LabError:
            return False
        points, colours = preview_segments(spec, snap.width / 2, snap.height / 2)
        self.hide_preview()
        if len(points):
            self._preview = self.client.scene.add_line_segments(
                "/builder/preview", points, colors=colours, thickness=0.002
            )
        return True

    def say(self, text: str) -> None:
        self.notice.content = escape_md(text).replace("\n", "  \n")
        self.notice.visible = True

    def _ready(self) -> WorldFeed | None:
        if not self.allowed:
            self.say(REFUSED)
            return None
        if self.feed is None:
            self.say("Press 'Show this arena' first.")
        return self.feed

    def _list(self) -> None:
        feed = self._ready()
        if feed is None:
            return
        try:
            reply = feed.robot_types()
        except LabError as exc:
            self.say(f"Could not list the robot types: {exc}")
            return
        names = [t.name for t in reply.types]
        self.start_from.options = tuple(names) or (NO_TYPES,)
        # The world's component types (its plugins' too), not only this page's.
        self.world_kinds = tuple(reply.component_types)
        if self.world_kinds:
            self.kind.options = self.world_kinds
        self.say(f"This world has {len(names)} robot types: {', '.join(names)}.")

    def _open(self) -> None:
        feed = self._ready()
        name = self.start_from.value
        if feed is None:
            return
        if name == NO_TYPES:
            self.say("Press 'List types' and choose one first.")
            return
        try:
            text = feed.robot_file(name)
        except LabError as exc:
            self.say(f"Could not open {name}: {exc}")
            return
        set_value(self.text, text)
        self.say(f"Opened {name}: rename it (name = ...) before you save your own.")

    def _add(self) -> None:
        if not self.allowed:
            self.say(REFUSED)
            return
        kind = self.kind.value
        if kind not in registry.default().components:
            snippet = f'\n[components.{kind}]\ntype = "{kind}"\n'
            said = f"Added a {kind} (a component of the world this page does not describe)."
        else:
            snippet = component_snippet(kind, self.text.value)
            said = f"Added a {kind}: set its numbers, then Check."
        set_value(self.text, self.text.value.rstrip("\n") + "\n" + snippet)
        self.say(said)

    def _check(self) -> None:
        self.check_now()

    def check_now(self) -> bool:
        """Validate the text as the world will (this page's components); say every problem."""
        try:
            spec = parse(
                self.text.value.encode("utf-8"), "robot file", registry.default().components
            )
        except RobotFileError as exc:
            page_only = [
                p
                for p in exc.problems
                if "unknown component type" in p.message
                and any(f"'{k}'" in p.message for k in self.world_kinds)
            ]
            if page_only and len(page_only) == len(exc.problems):
                self.say(
                    "Check: this page does not know some of the world's components; "
                    "the world checks the file when you save it."
                )
                return True
            self.say(f"Check: {len(exc.problems)} problem(s)\n{exc}")
            return False
        parts = ", ".join(f"{c.name} ({c.type})" for c in spec.components)
        drawn = " Drawn at the arena's centre." if self.show_preview(spec) else ""
        self.say(f"Check: {spec.name} is a valid robot type: {parts}.{drawn}")
        return True

    def _save(self) -> None:
        feed = self._ready()
        if feed is None:
            return
        try:
            said, name = feed.save_robot_type(self.text.value)
        except LabError as exc:
            self.say(f"Not saved: {exc}")
            return
        self.hide_preview()  # the drawing was of the file; robots of it now show themselves
        self.say(said[:1].upper() + said[1:] + ". Add robots of it with the map editor.")
        for call in self.on_saved:
            call(name)
