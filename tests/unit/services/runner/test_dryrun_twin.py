"""A dry run's private copy of a real arena: k1 is simulated by its twin, k2 by the datasheet."""

from __future__ import annotations

import json
import time

from common.messages import AgentInfo, WorldSnapshot
from common.twin.twinfile import parse_twin
from services.runner.dryrun import world_from_snapshot
from tests.unit.common.twin.test_twin_store import calibration


def robot(ident: str, x: float) -> AgentInfo:
    return AgentInfo(
        id=ident, type="khepera", radius=27.5, colour="#2e8b57", x=x, y=500.0, heading=0.0,
        gripper=False, leds=2, proximity_sensors=[], proximity_max=1023, speed_limit=127,
    )  # fmt: skip


def test_the_copy_of_a_real_arena_drives_the_twins_robot_by_its_fitted_drive() -> None:
    snap = WorldSnapshot(
        world="real", tick=0, sim_time=0.0, layout=0, tick_s=0.01, seed=0, width=1000.0,
        height=1000.0, items=[], lights=[], agents=[robot("k1", 300.0), robot("k2", 700.0)],
        rows=["k1", "k2"], kind="real",
    )  # fmt: skip
    twin = parse_twin(calibration().to_json("carol", time.time() - 3600))
    world = world_from_snapshot(snap, twin)
    k1, k2 = (world.agents[world.agent_slot(a)].spec for a in ("k1", "k2"))
    assert k1.name == "twin-k1" and k2.name == "khepera"
    assert (k1.drive.wheel_scale, k1.drive.wheel_base_mm) == ((0.96, 0.99), 55.0)
    # The same IR curve, read through each sensor's fitted gain (the datasheet's: 1 each).
    assert k1.proximity.curve == k2.proximity.curve
    assert k1.proximity.gains == twin.ir_gains and twin.ir_gains[2] == 1.1
    assert k2.proximity.gains == ()
    assert world.tables.imperfect == (world.agent_slot("k1"),)
    # Without a twin the copy is the snapshot's, as before.
    plain = world_from_snapshot(snap)
    assert {a.spec.name for a in plain.agents} == {"khepera"}
    assert json.loads(twin.text)["robot"] == "k1"
