"""What `wart robots` prints and what the page's builder adds, both from the schemas."""

from __future__ import annotations

import pytest

from common.robots import registry
from common.robots.robotfile import RobotFileError, parse
from services.commands import robots
from tests.unit.common.robots.test_robotfile import GOOD
from viewers.web.builder import component_snippet

REG = registry.build(plugins=False)


def test_describe_prints_each_parameter_with_its_unit_default_and_range(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert robots.main(["describe", "range_finder"]) == 0
    out = capsys.readouterr().out
    assert "range_finder  (sensor, from built-in)" in out
    assert "max_range_mm  number [mm], default 500, range 10..5000: farthest distance" in out
    assert "beams         integer, default 1, range 1..64: number of rays" in out
    assert robots.main(["describe", "khepera"]) == 0
    out = capsys.readouterr().out
    assert "[components.proximity] type = ir_proximity" in out
    assert "    mass_g = 70 g  (default required: mass" in out
    assert "robot.close_gripper" in out


def test_describe_of_an_unknown_name_says_what_there_is(capsys: pytest.CaptureFixture[str]) -> None:
    assert robots.main(["describe", "teleporter"]) == 1
    err = capsys.readouterr().err
    assert "no robot or component type 'teleporter' (known: epuck, khepera" in err


@pytest.mark.parametrize("kind", sorted(REG.components))
def test_the_builder_s_table_for_each_component_validates_but_for_what_it_requires(
    kind: str,
) -> None:
    """A component added in the builder is valid TOML at its defaults; the only problems
    are the parameters it requires (said as such) or a second body or drive."""
    text = GOOD + component_snippet(kind, GOOD)
    try:
        spec = parse(text, "built.toml", REG.components)
    except RobotFileError as exc:
        for p in exc.problems:
            assert "is required" in p.message or "a robot has one" in p.message, p
        return
    assert any(c.type == kind for c in spec.components)


def test_the_documented_calls_are_the_calls_check_allows() -> None:
    """The schemas' ApiCall lists (docs, `describe`) and the controller package's ROLE_CALLS
    (what Check allows; stdlib only, so written twice) name the same calls per role."""
    from common.controller.robot import ROLE_CALLS

    for component in REG.components.values():
        if component.role == "sensor" or component.role == "body":
            continue
        documented = {call.call.split("(")[0] for call in component.api}
        assert documented == set(ROLE_CALLS[component.role]), component.name


def test_the_builder_draws_the_composed_robot_from_its_components() -> None:
    """Each component draws itself: the rim and heading, each IR ray to the table's reach,
    each light sensor's tick, a range finder's beams at full range (metres, at x, y)."""
    from viewers.web.builder import ROLE_COLOURS, preview_segments

    khepera = REG.robots["khepera"]
    points, colours = preview_segments(khepera, 500.0, 400.0)
    assert points.shape == (32 + 1 + 8 * 3 + 8, 2, 3) and colours.shape == (len(points), 2, 3)
    assert tuple(colours[0, 0]) == ROLE_COLOURS["body"]
    assert tuple(colours[40, 0]) == ROLE_COLOURS["proximity"]
    heading = points[32]
    assert heading[0, :2].tolist() == pytest.approx([0.5, 0.4])
    assert heading[1, :2].tolist() == pytest.approx([0.5 + 1.3 * 0.0275, 0.4])
    scout = parse(GOOD, "scout.toml", REG.components)  # its eye: 5 beams over 60°
    points, colours = preview_segments(scout, 0.0, 0.0)
    beams = points[-5:]
    assert tuple(colours[-1, 0]) == ROLE_COLOURS["sensor"]
    lengths = [float(abs(complex(*(b[1, :2] - b[0, :2])))) for b in beams]
    assert lengths == pytest.approx([0.5] * 5)  # max_range_mm 500 at its default
