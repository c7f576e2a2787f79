"""Pure parts of the real adapters: snapshot conversion, edits, the admin's lab list."""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import pytest

from common.messages import (
    AddItem,
    AgentContextState,
    AgentInfo,
    AgentQueue,
    ItemInfo,
    LightInfo,
    MoveItem,
    QueueEntry,
    RemoveItem,
    ResizeArena,
    ShapeInfo,
    WorldSnapshot,
)
from viewers.web.adapters import AgentStatus, ArenaSettings, LabError
from viewers.web.lab_links import load_labs
from viewers.web.live_agents import agent_rows
from viewers.web.live_world import convert_snapshot, to_wire_edit
from viewers.web.robot_panel import format_agents
from viewers.web.world_feed import MapEdit

KEY = "11" * 32


def wire_snapshot() -> WorldSnapshot:
    box = ShapeInfo(kind="polygon", points=[(-50, -20), (50, -20), (50, 20), (-50, 20)])
    return WorldSnapshot(
        world="w1",
        tick=5,
        sim_time=0.1,
        layout=7,
        tick_s=0.02,
        seed=1,
        width=1600,
        height=1200,
        items=[
            ItemInfo(
                id="crate",
                category="obstacle",
                kind="box",
                shape=box,
                x=300,
                y=400,
                heading=0.5,
                colour="#808080",
            ),
            ItemInfo(
                id="pillar",
                category="obstacle",
                kind="circle",
                shape=ShapeInfo(kind="circle", radius=40),
                x=800,
                y=600,
                heading=0,
                colour="#808080",
            ),
            ItemInfo(
                id="ball0",
                category="object",
                kind="ball",
                shape=ShapeInfo(kind="circle", radius=15),
                x=100,
                y=100,
                heading=0,
                colour="#ff0000",
            ),
            ItemInfo(
                id="nest",
                category="zone",
                kind="nest",
                shape=box,
                x=10,
                y=10,
                heading=0,
                colour="#00ff00",
            ),
        ],
        lights=[
            LightInfo(
                id="lamp",
                x=5,
                y=6,
                intensity=1,
                radius=300,
                mode="on",
                period=1,
                colour="#ffff00",
                on=True,
            )
        ],
        agents=[
            AgentInfo(
                id="k0",
                type="khepera",
                radius=27.5,
                colour="#0000ff",
                x=1,
                y=2,
                heading=0,
                gripper=True,
                leds=2,
                proximity_sensors=[],
                proximity_max=1023,
                speed_limit=127,
            )
        ],
        rows=["k0", "ball0"],
    )


def test_convert_snapshot() -> None:
    view, object_rows = convert_snapshot(wire_snapshot())
    assert view.version == 7 and view.robots == ("k0",) and object_rows == ("ball0",)
    crate, pillar = view.obstacles
    assert (crate.w, crate.h, crate.angle) == (100, 40, 0.5) and not crate.round
    assert pillar.round and pillar.w == 80
    assert [b.ident for b in view.balls] == ["ball0"] and view.balls[0].r == 15
    assert view.lights[0].on and view.robot_radius == 27.5


def test_edits_become_engine_ops_and_junk_is_refused() -> None:
    snap, _ = convert_snapshot(wire_snapshot())
    move = to_wire_edit(MapEdit("move", "obstacle", "crate", x=10, y=20, angle=1.0), snap)
    assert move == MoveItem(id="crate", x=10, y=20, heading=1.0)
    assert to_wire_edit(MapEdit("delete", "ball", "ball0"), snap) == RemoveItem(id="ball0")
    assert to_wire_edit(MapEdit("resize", "arena", w=900, h=800), snap) == ResizeArena(
        width=900, height=800
    )
    add = to_wire_edit(MapEdit("add", "agent", x=50, y=60, angle=math.pi / 2), snap)
    assert isinstance(add, AddItem) and add.section == "agents"
    assert add.entry["id"] == "k1" and add.entry["heading_deg"] == pytest.approx(90)
    box = to_wire_edit(MapEdit("add", "obstacle", x=50, y=60, w=150, h=150), snap)
    assert isinstance(box, AddItem) and box.entry["shape"] == "box" and box.entry["id"] == "box1"
    with pytest.raises(LabError, match="not finite"):
        to_wire_edit(MapEdit("move", "obstacle", "crate", x=float("nan")), snap)
    with pytest.raises(LabError, match="positive"):
        to_wire_edit(MapEdit("resize", "arena", w=0, h=10), snap)
    with pytest.raises(LabError, match="select"):
        to_wire_edit(MapEdit("move", "obstacle", "../x"), snap)


def test_lab_list_is_validated(tmp_path: Path) -> None:
    path = tmp_path / "labs.json"
    assert load_labs(path, "lab") == {}
    path.write_text(
        json.dumps(
            {
                "labs": [
                    {"address": "wart://physics.example.org/phys", "registry_key": KEY},
                    {"address": "bad host!", "registry_key": KEY},
                    {"address": "other.example.org", "registry_key": "not-hex"},
                    "junk",
                ]
            }
        )
    )
    labs = load_labs(path, "lab")
    assert list(labs) == [("physics.example.org", 7447, "phys")]
    path.write_text("{not json")
    assert load_labs(path, "lab") == {}


def test_offline_robots_are_marked() -> None:
    snap = wire_snapshot()
    offline = msgspec.structs.replace(
        snap, agents=[msgspec.structs.replace(snap.agents[0], online=False)]
    )
    assert convert_snapshot(snap)[0].offline == frozenset()
    assert convert_snapshot(offline)[0].offline == {"k0"}
    assert "k0 (offline)" in format_agents([AgentStatus("k0", None, 0, online=False)])


def test_queue_state_as_panel_rows() -> None:
    now = 1000.0
    state = AgentContextState(
        ctx="arena",
        world="w1",
        slot_seconds=3.0,
        enabled=True,
        agents=[
            AgentQueue(
                agent="k0",
                type="khepera",
                enabled=True,
                entries=[
                    QueueEntry(
                        request_id="r1",
                        user="alice",
                        mode="deploy",
                        position=0,
                        start_eta=now - 1,
                        end=now + 2,
                    ),
                    QueueEntry(
                        request_id="r2", user="bob", mode="deploy", position=1, start_eta=now + 2
                    ),
                ],
            ),
            AgentQueue(agent="k1", type="khepera", enabled=False, entries=[]),
        ],
        at=now,
    )
    k0, k1 = agent_rows(state, "bob", now, frozenset({"k1"}))
    assert (k0.holder, k0.queue, k0.my_position, k0.my_request) == ("alice", 1, 1, "r2")
    assert k0.eta_s == pytest.approx(2.0) and k0.slot_left_s == pytest.approx(2.0)
    assert (k1.holder, k1.enabled, k1.online, k1.my_position) == (None, False, False, None)
    mine = agent_rows(state, "alice", now)[0]
    assert (mine.my_position, mine.eta_s) == (0, None)  # running: no ETA
    table = format_agents([k0, k1], ArenaSettings(3.0, True, False))
    assert "Slots of 3 s" in table and "alice (2 s left)" in table and "#1" in table


def test_the_teachers_table_names_the_queue_and_a_take_over() -> None:
    now = 1000.0
    running = QueueEntry(
        request_id="r1",
        user="alice",
        mode="deploy",
        position=0,
        start_eta=now - 1,
        end=now + 9,
        taken_by="ida",
        taken_at=now - 0.5,
    )
    waiting = QueueEntry(request_id="r2", user="bob", mode="deploy", position=1, start_eta=now)
    state = AgentContextState(
        ctx="arena",
        world="w1",
        slot_seconds=10.0,
        enabled=True,
        agents=[AgentQueue(agent="k0", type="khepera", enabled=True, entries=[running, waiting])],
        at=now,
    )
    (row,) = agent_rows(state, "ida", now)
    assert (row.holder, row.taken_by, row.waiting) == ("alice", "ida", ("bob",))
    teacher = format_agents([row], ArenaSettings(10.0, True, True))
    assert "alice (9 s left), **taken over by ida** (paused)" in teacher
    assert "| 1: bob |" in teacher
    student = format_agents([row], ArenaSettings(10.0, True, False))
    assert "taken over by ida" in student and "bob" not in student  # names: managers only
