"""What a recorded robot touched: counted from poses as the dry run's physics counts it."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import numpy as np

from common.messages import AgentInfo, WorldSnapshot
from common.recording import contacts
from common.recording import schema as s
from common.recording.reader import Recording, Stamped
from common.sim2d import maps
from common.world import packing

REPO = Path(__file__).resolve().parents[3]


def _snap(drive: str = "joints") -> WorldSnapshot:
    # The foraging arena: k0 stands 120 mm behind k2, both facing +x. On the joints drive
    # the gripper's tongs collide with robots and walls; on the others they touch objects only.
    world = maps.load_map(REPO / "maps" / "foraging.json", name="w1", seed=1, drive=drive)
    return packing.snapshot(world)


def _recording(snap: WorldSnapshot, k0_x: list[float]) -> Recording:
    rec = Recording(path=Path("run.mcap"))
    rows = snap.rows
    for i, x in enumerate(k0_x):
        xs = [a.x for a in snap.agents] + [0.0] * (len(rows) - len(snap.agents))
        ys = [a.y for a in snap.agents] + [0.0] * (len(rows) - len(snap.agents))
        xs[rows.index("k0")] = x
        frame = s.FrameRecord(
            tick=i,
            sim_time=i * 0.04,
            layout=snap.layout,
            agents=len(snap.agents),
            rows=list(rows),
            x=xs,
            y=ys,
            heading=[0.0] * len(rows),
            fingers=[0] * len(snap.agents),
        )
        rec.frames.append(Stamped(i * 0.04, frame))
    return rec


def test_the_snapshot_says_which_tongs_hit_robots_and_walls() -> None:
    k0 = contacts.agent_info(_snap(), "k0")
    assert k0 is not None and [t[2] for t in k0.tongs] == [16.0, -16.0]  # both sides, y in mm
    on_discs = contacts.agent_info(_snap("discs"), "k0")
    assert on_discs is not None and on_discs.tongs == []


def test_a_robot_pushed_along_is_one_collision_and_a_second_touch_is_another() -> None:
    snap = _snap()
    k2 = next(a for a in snap.agents if a.id == "k2")
    # k0's tong tips, 52 mm ahead and 16 mm aside (2 mm half width), meet k2's disc here:
    touch = k2.x - 52.0 - math.sqrt((k2.radius + 2.0) ** 2 - 16.0**2)
    path = [touch - 40, touch - 20, touch + 0.5, touch - 1.0, touch + 0.3, touch - 3.0]
    path += [touch - 30, touch - 30, touch + 0.2, touch + 0.2]
    rec = _recording(snap, path)
    gaps = contacts.robot_gaps(rec, "k0", snap)
    assert len(gaps) == len(path)
    by_kind, contact = contacts.count_collisions({"robot": gaps}, np.arange(len(path)) * 0.04)
    # a push that jitters by a few mm stays one collision; parting 30 mm ends it
    assert by_kind == {"robot": 2}
    assert contact > 0


def test_without_tongs_that_hit_robots_only_the_disc_counts() -> None:
    snap = _snap()
    bare = [msgspec.structs.replace(a, tongs=[]) for a in snap.agents]
    snap = msgspec.structs.replace(snap, agents=bare)
    k2 = next(a for a in snap.agents if a.id == "k2")
    touch_by_tongs = k2.x - 52.0 - math.sqrt((k2.radius + 2.0) ** 2 - 16.0**2)
    rec = _recording(snap, [touch_by_tongs - 10, touch_by_tongs + 1, touch_by_tongs + 1])
    by_kind, _ = contacts.count_collisions(
        {"robot": contacts.robot_gaps(rec, "k0", snap)}, np.arange(3) * 0.04
    )
    assert by_kind == {}


def test_tongs_touching_the_wall_count_as_a_collision_with_the_wall() -> None:
    snap = _snap()
    me: AgentInfo | None = contacts.agent_info(snap, "k0")
    x = np.array([snap.width - 80.0, snap.width - 52.5])  # then the tong tips at the wall
    y = np.array([500.0, 500.0])
    h = np.zeros(2)
    gaps = contacts.map_contact(snap, me.radius if me else 27.5, x, y, h, me)
    assert gaps["wall"][0] > contacts.CONTACT_MM
    assert gaps["wall"][1] <= contacts.CONTACT_MM
    assert contacts.map_contact(snap, 27.5, x, y)["wall"][1] > 20  # the disc alone: far off
