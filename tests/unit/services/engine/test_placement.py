"""Add robot: the world puts the new robot at the free spot nearest where it was asked for
(the arena's centre, or a click), clear of rocks, balls and robots, and refuses only when
the arena has no room; a restart replays it where it went.

The engine's own request handler with real sealed envelopes; only Zenoh's query is a
stand-in (as tests/unit/services/engine/test_reset.py).
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from common import keys
from common.auth import RegistryIdentity, issue_session
from common.messages import AddItem, EditResult, ErrorReply, Message, WorldEdit
from common.robots import registry
from common.sim2d import maps
from common.sim2d.world import World
from services.engine.service import EngineService, EngineSettings
from tests.unit.common.robots.test_world_types import SCOUT
from viewers.web.live_world import to_wire_edit
from viewers.web.world_feed import MapEdit, SceneLayout

REALM = "lab"
ROOM = {
    "format": "wart-map",
    "version": 1,
    "arena": {"width": 800, "height": 600},
    # A rock on the centre, a ball and a robot beside it: the centre's neighbours are taken.
    "obstacles": [{"id": "rock", "shape": "circle", "radius": 60, "x": 400, "y": 300}],
    "objects": [{"id": "ball1", "shape": "circle", "radius": 20, "x": 480, "y": 300}],
    "agents": [{"id": "k0", "x": 300, "y": 300}],
}


@dataclass
class Query:
    key_expr: str
    payload: bytes


class Engine:
    def __init__(self, maps_dir: Path, room: dict[str, Any] = ROOM) -> None:
        (maps_dir / "room.json").write_text(json.dumps(room))
        self.registry = RegistryIdentity.generate()
        self.maps_dir = maps_dir
        self.teacher = issue_session(self.registry, REALM, "teacher", ["edit_map"])
        self.engine = self._start()

    def _start(self) -> EngineService:
        world = maps.load_map(self.maps_dir / "room.json", name="w1")
        settings = EngineSettings(
            registry_key=bytes(self.registry.verify_key), maps_dir=self.maps_dir, base_map="room"
        )
        return EngineService(None, REALM, world, settings)  # type: ignore[arg-type]

    def restart(self) -> World:
        self.engine = self._start()
        return self.engine.world

    def add_robot(self, ident: str, x: float, y: float, kind: str = "khepera") -> Message:
        entry = {"id": ident, "type": kind, "x": x, "y": y, "heading_deg": 0.0}
        return self.edit(AddItem(section="agents", entry=entry, nearest_free=True))

    def edit(self, op: AddItem) -> Message:
        key = keys.world_edit(REALM, "w1")
        query = Query(key, self.teacher.seal(key, WorldEdit(op=op)))
        answer: list[Any] = []

        def ask() -> None:
            answer.append(self.engine._on_edit(query))  # type: ignore[arg-type]

        asker = threading.Thread(target=ask)
        asker.start()
        while asker.is_alive():
            self.engine._drain()
            asker.join(0.01)
        return answer[0]


def clear_of_everything(world: World, ident: str) -> None:
    x, y, _ = world.pose_of(ident)
    r = next(a.spec.radius_mm for a in world.agents if a.id == ident)
    assert r <= x <= world.width - r and r <= y <= world.height - r
    assert math.hypot(x - 400, y - 300) >= 60 + r  # the rock
    assert math.hypot(x - 480, y - 300) >= 20 + r  # the ball
    for a in world.agents:
        if a.id != ident:
            ax, ay, _ = world.pose_of(a.id)
            assert math.hypot(x - ax, y - ay) >= r + a.spec.radius_mm


def test_a_robot_asked_for_on_a_rock_stands_at_the_nearest_free_spot(tmp_path: Path) -> None:
    lab = Engine(tmp_path)
    done = lab.add_robot("k1", 400, 300)  # "Add robot": the centre, where the rock is
    assert isinstance(done, EditResult), done
    world = lab.engine.world
    clear_of_everything(world, "k1")
    x, y, _ = world.pose_of("k1")
    assert math.hypot(x - 400, y - 300) < 60 + 27.5 + 30  # beside the rock, not far away
    # The next one, asked for at the same spot, goes beside both.
    assert isinstance(lab.add_robot("k2", 400, 300), EditResult)
    clear_of_everything(world, "k2")
    # A click at the wall: beside it, inside the arena.
    assert isinstance(lab.add_robot("k3", 0, 0), EditResult)
    assert world.pose_of("k3")[:2] == pytest.approx((32.5, 32.5))
    # A restart replays each where it went (the journal has the spot, not the request).
    where = {a: world.pose_of(a)[:2] for a in ("k1", "k2", "k3")}
    again = lab.restart()
    assert {a: again.pose_of(a)[:2] for a in where} == pytest.approx(where)


def test_a_free_point_is_kept_as_asked(tmp_path: Path) -> None:
    lab = Engine(tmp_path)
    assert isinstance(lab.add_robot("k1", 150, 450), EditResult)
    assert lab.engine.world.pose_of("k1")[:2] == pytest.approx((150, 450))


def test_a_full_arena_refuses_in_words(tmp_path: Path) -> None:
    small = dict(ROOM, arena={"width": 200, "height": 200}, objects=[])
    small["obstacles"] = [{"id": "rock", "shape": "circle", "radius": 80, "x": 100, "y": 100}]
    small["agents"] = []
    lab = Engine(tmp_path, small)
    refused = lab.add_robot("k1", 100, 100)
    assert isinstance(refused, ErrorReply) and refused.code == "conflict"
    assert refused.message == (
        "no free spot for a khepera (55 mm across) in this arena: move or remove something first"
    )


def test_the_page_s_add_robot_asks_for_the_nearest_free_spot() -> None:
    snap = SceneLayout("w1", 800.0, 600.0, (), (), (), ("k0",))
    robot = to_wire_edit(MapEdit("add", "agent", x=400, y=300, robot_type="scout"), snap)
    assert isinstance(robot, AddItem) and robot.nearest_free
    assert robot.entry["type"] == "scout" and (robot.entry["x"], robot.entry["y"]) == (400, 300)
    ball = to_wire_edit(MapEdit("add", "ball", x=400, y=300), snap)
    assert isinstance(ball, AddItem) and ball.nearest_free
    box = to_wire_edit(MapEdit("add", "obstacle", x=400, y=300, w=100, h=100), snap)
    assert isinstance(box, AddItem) and not box.nearest_free  # a box goes where it is put


def test_a_ball_asked_for_on_a_robot_lies_beside_it(tmp_path: Path) -> None:
    lab = Engine(tmp_path)
    entry = {"id": "ball2", "shape": "circle", "radius": 20.0, "x": 300.0, "y": 300.0}
    done = lab.edit(AddItem(section="objects", entry=entry, nearest_free=True))
    assert isinstance(done, EditResult), done
    x, y, _ = lab.engine.world.pose_of("ball2")
    assert math.hypot(x - 300, y - 300) >= 27.5 + 20  # clear of k0, where it was asked for
    assert math.hypot(x - 400, y - 300) >= 60 + 20  # and of the rock


def test_a_robot_of_a_type_the_world_s_map_brought_can_be_added_live(tmp_path: Path) -> None:
    """A map from another lab carries its robot type; this engine never had it, yet the
    map editor adds another robot of it, sharing its spec, and a restart replays it."""
    room = dict(ROOM, robot_types={"scout": SCOUT})
    room["agents"] = [*ROOM["agents"], {"id": "s0", "type": "scout", "x": 150, "y": 150}]  # type: ignore[misc]
    lab = Engine(tmp_path, room)
    assert "scout" not in registry.default().robots
    assert isinstance(lab.add_robot("s1", 650, 450, kind="scout"), EditResult)
    world = lab.engine.world
    s0, s1 = (next(a for a in world.agents if a.id == i) for i in ("s0", "s1"))
    assert s1.spec is s0.spec and s1.spec.name == "scout"
    again = lab.restart()
    assert again.pose_of("s1")[:2] == pytest.approx(world.pose_of("s1")[:2])
