"""The engine's live edits: edit, reset and map requests, and the journal that replays them.

An acknowledged edit survives a crash: it is appended (synced) to the
world's journal before the reply, and replayed on the map it was made on at
the next start. A part of :class:`~services.engine.service.EngineService`,
which hands it these requests: it runs them on the service's sim thread, and
a map loaded on request replaces the service's world there.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from common.auth import AuthError, Principal, Verifier
from common.files import Journal
from common.messages import (
    AddItem,
    EditResult,
    MapRequest,
    Message,
    MessageError,
    MoveItem,
    RemoveItem,
    ResetAgent,
    ResizeArena,
    RobotTypeReply,
    RobotTypeRequest,
    RotateItem,
    WorldEdit,
    decode,
    encode,
)
from common.robots import registry as robot_registry
from common.robots.robotfile import RobotFileError
from common.service import RequestError
from common.sim2d import maps
from common.sim2d.map_robots import MapRobotTypes
from common.sim2d.placement import free_spot
from common.sim2d.world import EditError, World
from common.world.leases import LeaseBook
from common.world.world_service import robot_types


class EngineEdits:
    """The engine's edit, reset, robot-type and map requests, and its journal."""

    def __init__(
        self,
        *,
        ident: str,
        maps_dir: Path,
        load_map: Callable[[Path], World],
        verifier: Verifier | None,
        leases: LeaseBook,
        current_world: Callable[[], World],
        in_sim: Callable[[Callable[[World], Message]], Message],
        use_world: Callable[[World], None],
        log: logging.Logger,
    ) -> None:
        """``maps_dir`` holds the maps and the journal; ``load_map`` makes a map file
        the engine's world (its name, seed, tick, threads); ``current_world`` is the
        world the engine steps now; ``in_sim`` runs a function on its sim thread
        between ticks and returns its reply; ``use_world`` (sim thread) makes a map
        loaded on request the world the engine steps."""
        self.ident = ident
        self.maps_dir = maps_dir
        self.load_map = load_map
        self.verifier = verifier
        self.leases = leases
        self.current_world = current_world
        self.in_sim = in_sim
        self.use_world = use_world
        self.log = log
        self.journal: Journal | None = None
        self.replayed_edits = 0

    def _open(self, key: str, payload: Any, expected: Any) -> tuple[Principal, Any]:
        if self.verifier is None:
            raise AuthError("unauthenticated", "this engine was started without --registry-key")
        return self.verifier.open(key, payload, expected)

    # -- the journal of live edits (an acknowledged edit survives a crash)

    def replay_journal(self, base: str, world: World) -> World:
        """Open the journal of the edits made since map ``base`` was loaded, replay them
        on ``world`` (that map's) and return the world they make (before the sim thread
        starts)."""
        try:
            marker = encode(MapRequest(action="load", name=base))
        except MessageError:
            self.log.warning("map name %r is not a plain name: live edits are not journalled", base)
            return world
        journal = Journal(self.maps_dir / f".{self.ident}.edits")
        records = list(journal.records())
        if not records or records[0] != marker:
            journal.restart(marker)  # a journal of another map, or none: start afresh
        else:
            for raw in records[1:]:
                try:
                    world = self._replay(world, decode(raw, (WorldEdit, MapRequest)))
                except (MessageError, RequestError, maps.MapError, EditError) as exc:
                    self.log.warning("skipped a journalled edit that no longer applies: %s", exc)
            if self.replayed_edits:
                self.log.info(
                    "replayed %d live edits since %s was loaded (journal %s)",
                    self.replayed_edits,
                    base,
                    journal.path,
                )
        self.journal = journal
        return world

    def _replay(self, world: World, record: Message) -> World:
        if isinstance(record, WorldEdit):
            self._apply_op(world, record.op)
        elif isinstance(record, MapRequest) and record.action == "load" and record.name:
            path = maps.map_path(self.maps_dir, record.name)
            world = self.load_map(path)
        self.replayed_edits += 1
        return world

    def _journal_append(self, record: Message) -> None:
        if self.journal is not None:
            self.journal.append(encode(record))

    # -- live edits, map save and load (sealed, ``edit_map``; a reset by the lease holder)

    def on_edit(self, query: zenoh.Query) -> Message:
        principal, edit = self._open(str(query.key_expr), query.payload, WorldEdit)
        op = edit.op
        if isinstance(op, ResetAgent):
            return self._reset(principal, op)
        principal.require("edit_map", "edit the world")

        def apply(world: World) -> Message:
            try:
                done = self._apply_op(world, op)
            except (EditError, maps.MapError) as exc:
                raise RequestError("conflict", str(exc)) from None
            # Synced before the edit is acknowledged; a robot placed at a free spot is
            # journalled where it went, so a replay puts it there again.
            self._journal_append(edit if done is op else WorldEdit(op=done))
            self.log.info("%s edited the world: %s", principal.user, type(op).__name__)
            return EditResult(layout=world.layout, detail=type(op).__name__)

        return self.in_sim(apply)

    def _reset(self, principal: Principal, op: ResetAgent) -> Message:
        """A robot back at its start pose: its lease's holder or requester, or a map editor.

        Not journalled: it changes where a robot is, not the map (a restart puts
        every robot at its start pose anyway).
        """
        refused = self.leases.may_reset(principal, op.id)
        if refused is not None:
            raise AuthError("forbidden", refused)

        def apply(world: World) -> Message:
            try:
                x, y, _ = world.reset_agent(op.id)
            except EditError as exc:
                raise RequestError("conflict", str(exc)) from None
            self.log.info("%s reset %s to its start pose", principal.user, op.id)
            return EditResult(layout=world.layout, detail=f"{op.id} is back at ({x:.0f}, {y:.0f})")

        return self.in_sim(apply)

    @staticmethod
    def _apply_op(world: World, op: Any) -> Any:
        """Apply an edit op; the op as applied (an AddItem placed at a free spot: where)."""
        if isinstance(op, AddItem):
            # The lab's types and those the world's map brought: a robot of either is added.
            types = MapRobotTypes.of(a.spec for a in world.agents)
            if op.nearest_free and op.section in ("agents", "objects"):
                op = _placed(world, op, types)
            maps.add_entry(world, op.section, op.entry, op.section, types=types)
        elif isinstance(op, MoveItem):
            world.move(op.id, op.x, op.y, op.heading)
            world.set_home(op.id)  # a robot a map editor placed starts there from now on
        elif isinstance(op, RotateItem):
            world.rotate(op.id, op.heading)
            world.set_home(op.id)
        elif isinstance(op, RemoveItem):
            world.remove(op.id)
        elif isinstance(op, ResizeArena):
            world.resize(op.width, op.height)
        return op

    def on_robots(self, query: zenoh.Query) -> Message:
        """The world's robot types: list and get (any user), save (``edit_map``).

        A saved file is data: validated against the components this engine has
        (common/robots/), kept in its robot directory, and from then on a type
        the map editor can put into the arena (AddItem agents, ``type``).
        """
        principal, request = self._open(str(query.key_expr), query.payload, RobotTypeRequest)
        reg = robot_registry.default()
        if request.action == "list":
            return robot_types(reg)
        if request.action == "get":
            if request.name not in reg.texts:
                raise RequestError("not_found", f"no robot type {request.name!r} in this world")
            return RobotTypeReply(name=request.name, text=reg.texts[request.name])
        principal.require("edit_map", "add robot types")
        if not request.text:
            raise RequestError("bad_request", "save needs the robot file's text")
        data = request.text.encode("utf-8")

        def save(world: World) -> Message:
            # In the sim thread: maps and edits read the registry's types there.
            try:
                spec = reg.save_robot(data, frozenset(a.spec.name for a in world.agents))
            except RobotFileError as exc:
                raise RequestError("bad_request", str(exc)) from None
            except ValueError as exc:
                raise RequestError("conflict", str(exc)) from None
            self.log.info("%s saved robot type %s", principal.user, spec.name)
            parts = ", ".join(f"{c.name}:{c.type}" for c in spec.components)
            return RobotTypeReply(name=spec.name, detail=f"saved robot type {spec.name}: {parts}")

        return self.in_sim(save)

    def on_map(self, query: zenoh.Query) -> Message:
        principal, request = self._open(str(query.key_expr), query.payload, MapRequest)
        principal.require("edit_map", "save or load maps")
        maps_dir = self.maps_dir
        if request.action == "list":
            return EditResult(layout=self.current_world().layout, maps=maps.list_maps(maps_dir))
        if request.name is None:
            raise RequestError("bad_request", f"{request.action} needs a map name")
        try:
            path = maps.map_path(maps_dir, request.name)
        except maps.MapError as exc:
            raise RequestError("bad_request", str(exc)) from None
        if request.action == "save":

            def save(world: World) -> Message:
                written = maps.save_map(world, maps_dir, request.name or "")
                self.log.info("%s saved the world to %s", principal.user, written)
                return EditResult(layout=world.layout, detail=f"saved {written.name}")

            return self.in_sim(save)
        if not path.is_file():
            raise RequestError("not_found", f"no map named {request.name} in the maps directory")
        try:
            new_world = self.load_map(path)
        except maps.MapError as exc:
            raise RequestError("bad_request", str(exc)) from None

        def swap(world: World) -> Message:
            new_world.layout = world.layout + 1  # viewers must refetch the snapshot
            self.use_world(new_world)
            self._journal_append(request)
            self.log.info("%s loaded map %s", principal.user, path.name)
            return EditResult(layout=new_world.layout, detail=f"loaded {path.name}")

        return self.in_sim(swap)


def _placed(world: World, op: AddItem, types: MapRobotTypes) -> AddItem:
    """The robot (or round object) of ``op`` at the free spot nearest to where it was asked
    for (EditError if the arena has none); an entry add_entry will refuse anyway, or of
    another shape, is left as it is."""
    entry = dict(op.entry)
    asked = [
        float(v)
        for v in (entry.get("x"), entry.get("y"))
        if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
    ]
    if op.section == "agents":
        name = entry.get("type", "khepera")
        # A type the world carries is compiled already (its robots'): nothing can fail here.
        spec = types.spec(name, "") if isinstance(name, str) and name in types else None
        what, radius = f"a {name}", spec.radius_mm if spec is not None else None
    else:
        size: Any = entry.get("radius") if entry.get("shape") == "circle" else None
        number = isinstance(size, int | float) and not isinstance(size, bool)
        kind = entry.get("kind", "ball")
        what = f"a {kind}" if isinstance(kind, str) else "it"
        radius = float(size) if number and size > 0 else None
    if radius is None or len(asked) != 2:
        return op
    spot = free_spot(world, radius, *asked)
    if spot is None:
        raise EditError(
            f"no free spot for {what} ({2 * radius:.0f} mm across) in this arena: "
            "move or remove something first"
        )
    entry["x"], entry["y"] = round(spot[0], 1), round(spot[1], 1)
    return AddItem(section=op.section, entry=entry)
