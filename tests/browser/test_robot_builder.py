"""The robot builder in the page, against a real lab (issue 34): build, save, place, drive.

ida (an instructor: edit_map) starts from the e-puck's file as the world gives
it, adds a range finder from the component list, renames the type, Checks it
(a broken value first: refused with its line and field), saves it to the lab,
puts a robot of it into the arena with the map editor, and uploads a
controller that reads the range finder by its name in the file; its output
shows the readings. A student's page says the builder needs edit_map.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.browser.conftest import wait_until
from tests.browser.test_real_agents import choose, enter_arena, pick_robot, upload
from tests.browser.test_real_lab import session_of
from tests.conftest import needs_sandbox
from tests.kit.reallab import RealLab, real_lab

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

READER = b'''"""Reads the range finder the builder added."""

from common.controller import Controller


class Look(Controller):
    period = 0.2

    def do_work(self, robot) -> None:
        print(f"range reads {robot.range().values}")
        robot.set_speeds(0, 0)
'''


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    # the empty map: "Add robot" puts the new robot at the arena's centre, free there
    tmp = Path(tmp_path_factory.mktemp("builderlab"))
    with real_lab(tmp, "empty", agents=True, slot=30.0) as env:
        yield env


def test_build_a_robot_with_a_range_finder_save_place_and_drive_it(open_page, lab: RealLab) -> None:
    ida = open_page("ida")
    panel = enter_arena(ida, lab, "ida")
    view = session_of(lab.viewer, "ida").view
    wait_until(lambda: view.frames_applied > 3, 15, what="the arena in ida's view")
    builder = panel.builder
    assert builder is not None
    wait_until(lambda: builder.feed is not None, 10, what="the builder bound to the arena")

    ida.p.get_by_text("Robot builder").first.click()
    ida.click("List types")
    ida.wait_text("This world has")
    choose(ida, "Start from", "epuck")
    ida.click("Open type")
    ida.wait_text("Opened epuck")
    wait_until(lambda: 'name = "epuck"' in builder.text.value, 10, what="epuck's file")
    choose(ida, "Component", "range_finder")
    ida.click("Add component")
    wait_until(lambda: "[components.range]" in builder.text.value, 10, what="the range finder")

    scout = builder.text.value.replace('name = "epuck"', 'name = "scout"')

    def held(sent: str) -> str:
        page = ida.input_after_label("Robot file").input_value()
        return (
            f"the edit at the server: the page sent {len(sent)} characters and shows "
            f"{len(page)}{' (the same)' if page == sent else ''}; the server holds "
            f"{len(builder.text.value)} ending {builder.text.value[-60:]!r}"
        )

    def fill_robot_file(text: str) -> None:
        """Replace the robot file as a user would, once the page shows what the server holds.

        Playwright's fill selects all, then types: a server value landing in between (the
        "Add component" text reaching a busy page late) redraws the box and drops the
        selection, and the typing went after the old text (4,003 characters for 2,002).
        """
        box = ida.input_after_label("Robot file")
        wait_until(
            lambda: box.input_value() == builder.text.value,
            10,
            what=lambda: f"the page to show the server's robot file: {held(builder.text.value)}",
        )
        ida.fill("Robot file", text)
        wait_until(lambda: builder.text.value == text, 10, what=lambda: held(text))

    # Bad robot files, each refused in the page with the line and field a user reads.
    for bad, said in (
        (
            scout.replace("beams = 1", "beams = 99"),
            "components.range.beams: must be at most 64, got 99",
        ),
        (
            scout.replace('type = "range_finder"', 'type = "laser"'),
            "unknown component type 'laser'",
        ),
        (
            scout.replace("mass_g = 150.0", 'mass_g = "heavy"'),
            "components.body.mass_g: must be a number",
        ),
        (scout.replace("radius_mm = 35.0\n", ""), "components.body.radius_mm: is required"),
        (scout + "#" * 70_000, "robot files are limited to 65536"),
    ):
        fill_robot_file(bad)
        ida.click("Check robot file")
        ida.wait_text(said)
    three = scout.replace("beams = 1", "beams = 3")
    fill_robot_file(three)
    ida.click("Check robot file")
    ida.wait_text("Check: scout is a valid robot type")
    ida.wait_text("Drawn at the arena's centre")  # its body, rays and beams in the view
    assert builder._preview is not None
    ida.click("Save type to the lab")
    ida.wait_text("Saved robot type scout", timeout=15_000)
    ida.screenshot("builder-saved")

    editor = panel.editor
    assert editor is not None and editor.robot_type.value == "scout"
    before = set(view.robot_names)
    ida.p.get_by_text("Map editor").first.click()
    ida.click("Add robot")
    ida.screenshot("builder-add")
    wait_until(
        lambda: set(view.robot_names) - before,
        15,
        what=lambda: f"the scout in the arena ({editor.notice.content})",
    )
    (added,) = set(view.robot_names) - before
    assert view.feed is not None
    assert view.feed.snapshot().robot_types[added][0] == "scout"
    # The view draws each robot at its type's size: the e-puck-based scout (35 mm) beside
    # the Khepera (27.5 mm).
    wait_until(
        lambda: view.snapshot is not None and 35.0 in view.snapshot.robot_radii,
        10,
        what="the scout's radius in the view",
    )

    # The view takes the new snapshot, then rebuilds its robots' mesh (the pump's thread):
    # read the mesh once it is rebuilt.
    def scales() -> list[float]:
        robots = view._robots
        held = None if robots is None else robots.batched_scales
        return [] if held is None else sorted(float(s) for s in held)

    wait_until(lambda: len(scales()) == 2, 10, what=lambda: f"two robots' scales: {scales()}")
    assert scales() == pytest.approx([1.0, 35.0 / 27.5])

    pick_robot(ida, panel, added)
    # The selected robot is drawn as its components draw themselves (rim, rays, beams).
    wait_until(lambda: view._look.handle is not None, 10, what="the scout's look in the view")
    upload(ida, "look.py", READER)
    ida.wait_text("range reads (", timeout=30_000)
    ida.screenshot("builder-driven")
    ida.click("Cancel my request")
