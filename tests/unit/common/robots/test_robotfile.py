"""Robot files refused with the file, the line and the field; plugins refused with the reason.

What a user reads when their robot file is wrong (every problem at once), and
what the lab does with a plugin that fails to import or declares a bad schema:
it records the reason and runs without it.
"""

from __future__ import annotations

from importlib import metadata

import pytest

from common.robots import registry
from common.robots.robotfile import MAX_BYTES, RobotFileError, parse
from common.robots.schema import ComponentType, Param
from tests.conftest import REPO
from tests.kit.robots import wheeled_robot

COMPONENTS = registry.build(plugins=False).components

GOOD = wheeled_robot(
    "scout",
    """
[components.eye]
type = "range_finder"
beams = 5
fov_deg = 60.0
""",
)


def _refused(text: str) -> str:
    with pytest.raises(RobotFileError) as info:
        parse(text, "scout.toml", COMPONENTS)
    return str(info.value)


def test_a_good_file_compiles_with_its_parts_named_as_in_the_file() -> None:
    spec = parse(GOOD, "scout.toml", COMPONENTS)
    assert spec.name == "scout" and spec.radius_mm == 30.0 and spec.gripper is None
    assert [(c.name, c.type) for c in spec.components][-1] == ("eye", "range_finder")
    (eye,) = spec.parts
    assert (eye.name, eye.size, eye.values["max_range_mm"]) == ("eye", 5, 500.0)
    assert spec.proximity.poses == () and spec.sensor_reach_mm == 0.0


def test_an_unknown_component_type_names_the_line_and_what_the_lab_has() -> None:
    text = GOOD.replace('type = "range_finder"', 'type = "laser_cannon"')
    message = _refused(text)
    assert message.startswith("scout.toml:18: components.eye.type: unknown component type")
    assert "'laser_cannon'" in message and "range_finder" in message


def test_a_wrong_type_names_the_line_and_the_field() -> None:
    message = _refused(GOOD.replace("mass_g = 80.0", 'mass_g = "heavy"'))
    assert message == "scout.toml:8: components.body.mass_g: must be a number, got 'heavy'"


def test_a_value_out_of_range_says_the_range_and_unit() -> None:
    message = _refused(GOOD.replace("beams = 5", "beams = 500"))
    assert message == "scout.toml:19: components.eye.beams: must be at most 64, got 500"


def test_a_missing_field_is_refused_with_its_meaning() -> None:
    message = _refused(GOOD.replace("wheel_base_mm = 50.0\n", ""))
    assert message.startswith("scout.toml:10: components.drive.wheel_base_mm: is required")
    assert "distance between the wheels" in message


def test_an_unknown_parameter_lists_the_component_s_parameters() -> None:
    message = _refused(GOOD.replace("fov_deg = 60.0", "fov_deg = 60.0\ncolour = 3"))
    assert message.startswith("scout.toml:21: components.eye.colour: unknown parameter")
    assert "max_range_mm" in message


def test_every_problem_is_reported_at_once_and_nothing_is_built() -> None:
    text = GOOD.replace("mass_g = 80.0", "mass_g = -1").replace("beams = 5", "beams = 0")
    with pytest.raises(RobotFileError) as info:
        parse(text, "scout.toml", COMPONENTS)
    assert [p.field for p in info.value.problems] == [
        "components.body.mass_g",
        "components.eye.beams",
    ]


def test_a_huge_file_is_refused_before_it_is_read_as_toml() -> None:
    message = _refused(GOOD + "#" * MAX_BYTES)
    size = len(GOOD) + MAX_BYTES
    assert message == f"scout.toml: file: is {size} bytes; robot files are limited to {MAX_BYTES}"


def test_broken_toml_says_the_line() -> None:
    message = _refused(GOOD.replace("mass_g = 80.0", "mass_g = = 80"))
    assert message.startswith("scout.toml:8: file: is not valid TOML")


def test_a_file_nested_thousands_deep_is_refused_in_words_not_a_traceback() -> None:
    message = _refused(GOOD + "deep = " + "[" * 5000 + "]" * 5000 + "\n")
    assert message == (
        "scout.toml: file: is not valid TOML: arrays or tables nested more than 64 deep"
    )


def test_a_robot_needs_a_body_and_a_drive_and_one_of_each_ring() -> None:
    no_drive = GOOD.split("[components.drive]")[0]
    assert "a robot needs a drive component" in _refused(no_drive)
    twice = GOOD + '\n[components.body2]\ntype = "body"\nradius_mm = 3.0\nmass_g = 1.0\n'
    assert "components.body2.type: a robot has one body" in _refused(twice)


def test_a_sensor_may_not_take_a_name_of_the_robot_api() -> None:
    message = _refused(GOOD.replace("[components.eye]", "[components.stop]"))
    assert "'stop' is a name of the robot's own API" in message


def _ep(name: str, group: str, value: str) -> metadata.EntryPoint:
    return metadata.EntryPoint(name=name, group=group, value=value)


class Sniffer(ComponentType):
    name = "sniffer"
    doc = "smells things"
    params = (Param("gain", "number", "how well", "", 1.0, lo=0.0, hi=2.0),)

    @classmethod
    def reading_size(cls, values):  # type: ignore[no-untyped-def]
        return 1

    @classmethod
    def measure(cls, world, slots, values, key):  # type: ignore[no-untyped-def]
        return [[0]] * len(slots)


class BadDefault(Sniffer):
    name = "bad_default"
    params = (Param("gain", "number", "how well", "", 9.0, lo=0.0, hi=2.0),)


def test_plugins_that_fail_are_recorded_with_the_reason_and_the_rest_load() -> None:
    reg = registry.build(plugins=False)
    here = __name__
    reg.load_entry_points(
        [
            _ep("good", "wart.components", f"{here}:Sniffer"),
            _ep("broken", "wart.components", "no_such_module_anywhere:Thing"),
            _ep("bad", "wart.components", f"{here}:BadDefault"),
            _ep("nomain", "wart.contexts", f"{here}:Sniffer"),
        ]
    )
    assert "sniffer" in reg.components and "bad_default" not in reg.components
    reasons = {p.name: p.reason for p in reg.problems}
    assert reasons["broken"].startswith("failed to import: ModuleNotFoundError")
    assert reasons["bad_default"] == (
        "bad schema: bad_default.gain: its default must be at most 2, got 9.0"
    )
    assert reasons["nomain"] == "has no main(argv)"
    assert "khepera" in reg.robots  # the lab runs without them


def test_a_refused_robot_file_in_the_lab_directory_leaves_the_others(tmp_path) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "scout.toml").write_text(GOOD)
    (tmp_path / "broken.toml").write_text(GOOD.replace('name = "scout"', 'name = "x"\nspeed = 3'))
    reg = registry.build(plugins=False, robots_dir=tmp_path)
    assert "scout" in reg.robots
    (problem,) = reg.problems
    assert problem.name == "broken.toml"
    assert problem.reason == (
        "broken.toml:4: speed: unknown field "
        "(a robot file has format, version, name, description, components)"
    )


def test_each_ir_sensors_gain_and_noise_is_checked_against_the_ring() -> None:
    khepera = (REPO / "common/robots/shipped/khepera.toml").read_text()
    each = "noise_counts = 2.0\nsensor_gains = [1, 1, 1, 0.5, 1, 1, 1, 1]\n"
    spec = parse(khepera.replace("noise_counts = 2.0\n", each), "k.toml", COMPONENTS)
    assert spec.proximity.gains == (1.0, 1.0, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0)
    assert spec.proximity.counts(3) == 2.0  # no sensor's own: the ring's noise_counts
    short = _refused(khepera.replace("noise_counts = 2.0\n", "sensor_gains = [1, 0.5]\n"))
    assert short.endswith(
        "components.proximity.sensor_gains: must hold one number per sensor (8), got 2"
    ), short
    negative = "sensor_noise_counts = [3, 3, -1, 3, 3, 3, 3, 3]\n"
    message = _refused(khepera.replace("noise_counts = 2.0\n", negative))
    assert message.endswith(
        "components.proximity.sensor_noise_counts: item 2: must be at least 0 counts, got -1"
    ), message
    # The datasheet's Khepera has none: each sensor reads the curve as it is.
    assert parse(khepera, "k.toml", COMPONENTS).proximity.gains == ()


def test_a_second_type_of_a_taken_name_is_refused_saying_where_the_first_came_from() -> None:
    reg = registry.build(plugins=False)
    assert not reg.add_component(reg.components["body"], "someplugin")
    assert reg.add_robot(reg.texts["khepera"].encode(), "khepera.toml", "otherdir") is None
    assert [str(p) for p in reg.problems] == [
        "wart.components body (from someplugin): "
        "a component type 'body' exists already (from built-in)",
        "wart.agents khepera.toml (from otherdir): "
        "a robot type 'khepera' exists already (from built-in)",
    ]
