"""The floor sensor, the range finder and the bumper, in a world, for every robot at once."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.robots import registry
from common.robots.robotfile import parse
from common.sim2d.entities import ShapeSpec
from common.sim2d.floor import FloorLayer, FloorLine
from common.sim2d.maps import MapError, build_world, world_to_map
from common.sim2d.parts import parts_of, read_parts
from common.sim2d.world import World
from tests.kit.robots import wheeled_robot

COMPONENTS = registry.build(plugins=False).components

ROBOT = wheeled_robot(
    "probe",
    """
[components.line]
type = "floor_sensor"
points = [[20.0, 0.0], [20.0, 30.0]]
noise = 0.0

[components.eye]
type = "range_finder"
pose = [30.0, 0.0, 0.0]
beams = 3
fov_deg = 90.0
max_range_mm = 300.0

[components.bump]
type = "bumper"
count = 4
reach_mm = 2.0
""",
)
PROBE = parse(ROBOT, "probe.toml", COMPONENTS)


def _world() -> World:
    world = World(600, 400, seed=3)
    world.floor = FloorLayer(
        "#ffffff", (FloorLine(((0.0, 200.0), (600.0, 200.0)), 20.0, "#000000"),)
    )
    return world


def test_the_floor_sensor_reads_the_line_under_each_point() -> None:
    world = _world()
    world.add_agent("a", PROBE, 100, 200, 0.0)
    world.add_agent("b", PROBE, 300, 100, 0.0)  # off the line: white under both points
    (a, b) = parts_of(world, [0, 1])
    assert a["line"] == [0, 255]
    assert b["line"] == [255, 255]


def test_the_range_finder_sees_walls_obstacles_and_robots_not_itself() -> None:
    world = _world()
    world.add_obstacle("block", ShapeSpec.box(20, 300), 400, 200)  # its face at x = 390
    world.add_agent("a", PROBE, 100, 200, 0.0)
    world.add_agent("b", PROBE, 230, 300, 0.0)  # on a's left beam, 141 mm from the sensor
    eye = parts_of(world, [0])[0]["eye"]
    # beams from right (-45°) to left (+45°); the sensor is 30 mm ahead of a's centre, at x=130
    right, ahead, left = eye
    assert ahead == 390 - 130  # the block's face
    assert right == round(200 * math.sqrt(2))  # the arena's lower wall, 200 mm below
    assert left == round(100 * math.sqrt(2) - 30)  # b's body (radius 30)
    text = ROBOT.replace("300.0", "100.0").replace('"probe"', '"short"')
    world.add_agent("c", parse(text, "short.toml", COMPONENTS), 300, 100, math.pi / 2)
    assert parts_of(world, [2])[0]["eye"] == [100, 100, 100]  # nothing within 100 mm


def test_the_bumper_presses_the_sector_that_touches() -> None:
    world = _world()
    world.add_agent("a", PROBE, 31, 200, 0.0)  # its back 1 mm from the left wall
    world.add_agent("b", PROBE, 200, 200, 0.0)
    world.add_agent("c", PROBE, 200, 261, 0.0)  # 1 mm from b, on b's left
    a, b, c = (p["bump"] for p in parts_of(world, [0, 1, 2]))
    # sectors: 0 front, 1 left, 2 back, 3 right
    assert a == [0, 0, 1, 0]
    assert b == [0, 1, 0, 0]
    assert c == [0, 0, 0, 1]


def test_every_robot_is_measured_in_one_call_per_part_and_a_seed_repeats(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []
    noisy = parse(ROBOT.replace("noise = 0.0", "noise = 5.0"), "probe.toml", COMPONENTS)
    world = World(3000, 3000, seed=11)
    for i in range(400):
        world.add_agent(
            f"r{i}", noisy, 60 + 140 * (i % 20), 60 + 140 * (i // 20), 0.1 * i, defer_tables=True
        )
    world.finish_agents()
    component = noisy.parts[0].component
    original = component.measure

    def counting(w, slots, values, key):  # type: ignore[no-untyped-def]
        calls.append(len(slots))
        return original(w, slots, values, key)

    monkeypatch.setattr(component, "measure", counting)
    readings = read_parts(world)
    monkeypatch.undo()
    assert calls == [400]
    assert readings["probe/eye"][1].shape == (400, 3)
    assert readings["probe/bump"][1].shape == (400, 4)
    line = readings["probe/line"][1]
    assert line.std() > 0  # the noise is there
    again = World(3000, 3000, seed=11)
    for i in range(400):
        again.add_agent(
            f"r{i}", noisy, 60 + 140 * (i % 20), 60 + 140 * (i // 20), 0.1 * i, defer_tables=True
        )
    again.finish_agents()
    assert np.array_equal(read_parts(again)["probe/line"][1], line)


def test_robots_with_parts_drive_in_a_world_and_their_readings_follow_the_tick() -> None:
    world = _world()
    world.add_agent("a", PROBE, 100, 230, 0.0)
    world.cmd[:] = [[50, 50]]
    first = parts_of(world, [0])[0]["eye"]
    assert first[1] == 300  # the far wall is 470 mm ahead: out of range
    world.run(0.5)  # 500 mm/s
    x = world.agent_pose[0, 0]
    assert x > 300
    assert abs(parts_of(world, [0])[0]["eye"][1] - (600 - x - 30)) <= 1


FLOOR_MAP = {
    "format": "wart-map",
    "version": 1,
    "arena": {"width": 500, "height": 400},
    "floor": {
        "colour": "#eeeeee",
        "lines": [{"points": [[50, 50], [450, 50], [450, 350]], "width": 18, "colour": "#101010"}],
    },
}


def test_a_map_carries_a_floor_layer_and_saves_it_back() -> None:
    world = build_world(FLOOR_MAP, name="w")
    assert world.floor is not None and len(world.floor.lines) == 1
    assert world_to_map(world, "w")["floor"] == {
        "colour": "#eeeeee",
        "lines": [
            {"points": [[50, 50], [450, 50], [450, 350]], "width": 18.0, "colour": "#101010"}
        ],
    }
    assert math.isclose(world.floor.sample(np.array([[450.0, 200.0]]))[0], 16.0, abs_tol=0.5)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"points": [[50, 50], [900, 50]]},
            "floor.lines[0].points[1]: [900, 50] is outside the arena",
        ),
        ({"points": [[50, 50]]}, "floor.lines[0].points: must be a list of 2 to 512"),
        ({"width": -3}, "floor.lines[0].width: must be between 0.1 and 1000, got -3"),
        ({"shade": 3}, "floor.lines[0].shade: is not a field of this entry"),
    ],
)
def test_a_bad_floor_layer_is_refused_with_its_field(change: dict, message: str) -> None:
    line = {**FLOOR_MAP["floor"]["lines"][0], **change}  # type: ignore[index]
    data = {**FLOOR_MAP, "floor": {"lines": [line]}}
    with pytest.raises(MapError) as info:
        build_world(data, name="w", source="m.json")
    assert message in str(info.value)


def test_the_floor_layer_travels_in_the_snapshot_and_the_view_draws_it() -> None:
    from common.messages import WorldSnapshot, decode, encode
    from common.world.packing import snapshot
    from viewers.web import geometry as geo
    from viewers.web.live_world import convert_snapshot

    world = build_world(FLOOR_MAP, name="w")
    snap = decode(encode(snapshot(world)), WorldSnapshot)
    (line,) = snap.floor_lines
    assert (line.points, line.width, line.colour) == (
        [(50.0, 50.0), (450.0, 50.0), (450.0, 350.0)],
        18.0,
        "#101010",
    )
    layout, _ = convert_snapshot(snap)
    ((points, width, colour),) = layout.floor_lines
    segments = geo.floor_line_segments(points)
    assert segments.shape == (2, 2, 3) and width == 18.0
    assert segments[1, 1, :2].tolist() == pytest.approx([0.45, 0.35])
    assert geo.hex_rgb(colour) == (16, 16, 16)


def test_each_robot_type_s_look_travels_once_in_the_snapshot() -> None:
    from common.messages import WorldSnapshot, decode, encode
    from common.world.packing import snapshot
    from viewers.web.live_world import convert_snapshot

    world = World(600, 400, seed=1)
    world.add_agent("a", PROBE, 100, 100, 0.0)
    world.add_agent("b", PROBE, 300, 100, 0.0)
    snap = decode(encode(snapshot(world)), WorldSnapshot)
    (look,) = snap.looks  # once per type
    assert look.type == "probe"
    # the rim (32) and heading, 2 floor points of 2 strokes, 3 beams, 4 bumper borders
    assert len(look.segments) == 33 + 4 + 3 + 4
    assert look.roles.count("sensor") == 11 and look.roles[0] == "body"
    layout, _ = convert_snapshot(snap)
    points, colours = layout.looks["probe"]
    assert points.shape == (44, 2, 3) and colours.shape == (44, 2, 3)
    assert points[33 + 4, 1, 0] == pytest.approx((30.0 + 300.0 * math.cos(math.radians(45))) / 1000)
