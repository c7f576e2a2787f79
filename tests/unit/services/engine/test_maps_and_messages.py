"""Map files (schema, errors, round trip) and the world wire types."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from common.messages import (
    AgentCommand,
    Lease,
    MapRequest,
    MessageError,
    MoveItem,
    SensorSample,
    WorldEdit,
    WorldFrame,
    WorldSnapshot,
    decode,
    encode,
)
from common.sim2d import maps, packs
from common.sim2d.agents import agent_type
from common.sim2d.maps import MapError
from common.sim2d.world import World
from common.world import packing
from services.engine.main import main
from tests.conftest import REPO

MAPS = REPO / "maps"


@pytest.mark.parametrize("name", ["empty", "maze", "foraging", "phototaxis", "swarm"])
def test_shipped_maps_load(name: str) -> None:
    world = maps.load_map(MAPS / f"{name}.json", name=name)
    assert world.agents
    if name == "swarm":
        assert len(world.agents) == 1000


def _map(**sections: object) -> str:
    return json.dumps(
        {"format": "wart-map", "version": 1, "arena": {"width": 500, "height": 500}, **sections},
        indent=1,
    )


def test_errors_name_the_field_and_line() -> None:
    with pytest.raises(MapError, match=r"line 1 column 2"):
        maps.parse_map("{oops}", "m")
    with pytest.raises(MapError, match="version"):
        maps.parse_map('{"format": "wart-map", "version": 9}', "m")
    text = _map(objects=[{"id": "b1", "shape": "circle", "x": 10, "y": 10, "radius": -3}])
    with pytest.raises(MapError, match=r"line \d+: objects\[0\]\.radius: must be positive"):
        maps.build_world(maps.parse_map(text), name="w", text=text)
    text = _map(agents=[{"id": "k1", "type": "roomba", "x": 100, "y": 100}])
    with pytest.raises(MapError, match=r"agents\[0\]\.type: must be one of epuck, khepera"):
        maps.build_world(maps.parse_map(text), name="w", text=text)
    text = _map(
        obstacles=[{"id": "o", "shape": "box", "x": 100, "y": 100, "width": 100, "height": 100}],
        agents=[{"id": "k1", "x": 110, "y": 100}],
    )
    with pytest.raises(MapError, match=r"k1.*overlap an obstacle"):
        maps.build_world(maps.parse_map(text), name="w", text=text)


def test_save_and_reload_round_trip(tmp_path: Path) -> None:
    world = maps.load_map(MAPS / "foraging.json", name="w")
    world.run(0.2)
    path = maps.save_map(world, tmp_path, "copy")
    again = maps.load_map(path, name="w")
    assert packing.rows(again) == packing.rows(world)
    assert np.allclose(again.agent_pose, world.agent_pose, atol=0.01)
    with pytest.raises(MapError):
        maps.map_path(tmp_path, "../escape")


def test_wire_messages_round_trip() -> None:
    world = maps.load_map(MAPS / "foraging.json", name="w")
    world.run(0.1)
    for message in (
        packing.frame(world),
        packing.sample(world, 0),
        packing.snapshot(world),
        packing.batch(world),
    ):
        assert decode(encode(message), type(message)) == message
    frame = packing.frame(world)
    assert isinstance(frame, WorldFrame)
    assert frame.poses.to_numpy().shape == (len(packing.rows(world)), 3)
    snap = packing.snapshot(world)
    assert isinstance(snap, WorldSnapshot) and snap.rows == packing.rows(world)
    sample = packing.sample(world, 0)
    assert isinstance(sample, SensorSample) and sample.gripper is not None
    for message in (
        AgentCommand(agent="k0", speeds=(10, -10), leds=[True, False], arm=200, grip=True),
        Lease(
            lease_id="L1",
            world="w",
            agent="k0",
            holder_user="u",
            holder_session=b"x" * 16,
            start=1.0,
            end=2.0,
        ),
        WorldEdit(op=MoveItem(id="a", x=1.0, y=2.0)),
        MapRequest(action="save", name="m"),
    ):
        assert decode(encode(message), type(message)) == message
    with pytest.raises(MessageError):
        decode(encode(AgentCommand(agent="k0")).replace(b"k0", b"k/"), AgentCommand)


def test_samples_report_each_agents_own_readings() -> None:
    world = World(1000.0, 1000.0, seed=2, name="w")
    world.add_agent("k", agent_type("khepera"), 300.0, 300.0)
    world.add_agent("e", agent_type("epuck"), 700.0, 700.0)
    world.add_agent("k2", agent_type("khepera"), 300.0, 700.0, gripper=False)
    world.set_speeds(0, 5, -3)
    world.set_leds(0, [False, True])
    world.set_arm(0, 200)
    world.run(0.5)
    samples = packing.samples(world, [2, 0, 1])
    assert [s.agent for s in samples] == ["k2", "k", "e"]
    k2, k, e = samples
    assert k.speeds == (5, -3) and k.leds[1] == 1 and k.gripper is not None
    assert k.gripper.arm == round(float(world.arm[0])) and k.gripper.fingers == "open"
    assert k.counters == (int(world.counters[0, 0]), int(world.counters[0, 1]))
    assert k.proximity == world.proximity[0, :8].tolist()
    assert k2.gripper is None
    epuck = agent_type("epuck")
    assert len(e.proximity) == len(epuck.proximity.poses)
    assert len(e.ambient) == len(epuck.ambient.poses)
    assert packing.samples(world, []) == []


def test_a_map_loads_with_the_thread_counts_asked_for() -> None:
    two = min(2, packs.MAX_THREADS)
    world = maps.load_map(REPO / "maps" / "swarm.json", name="w", threads=two, physics_threads=two)
    assert (world.threads, world.physics_threads) == (two, two)
    assert world.space.threaded == (two > 1)


@pytest.mark.parametrize("flag", ["--threads", "--physics-threads"])
def test_wart_engine_refuses_thread_counts_outside_numbas_pool(flag: str, capsys) -> None:
    for bad in ("0", str(packs.MAX_THREADS + 1)):
        with pytest.raises(SystemExit) as exc:
            main(["--map", str(REPO / "maps" / "empty.json"), flag, bad])
        assert exc.value.code == 2
        assert f"{flag} must be between 1 and" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("bad", "said"), [("-1", "must be 0 or more"), ("many", "invalid int value")]
)
def test_wart_engine_refuses_a_bad_streams_up_front(bad: str, said: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--map", str(REPO / "maps" / "empty.json"), "--streams-up-front", bad])
    assert exc.value.code == 2
    assert said in capsys.readouterr().err
