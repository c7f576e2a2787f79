"""A real lab records a student's slot; the page lists it as hers and replays it.

Router, registry, engine, runner and the agent context ``arena`` (2 s slots, its
data dir keeps recordings). alice runs a tiny controller from the page; when the
slot ends her Recordings folder lists the run (robot, how it ended, duration)
and Replay draws it in her view. The arena's owner (ida), and she alone, is offered to
keep a fitted twin; the registry's answer shows under the button.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from playwright.sync_api import expect

from services.bridge.rehearse import rehearse
from tests.browser.conftest import settle, wait_until
from tests.browser.test_real_agents import enter_arena, pick_robot, upload
from tests.browser.test_real_lab import session_of
from tests.conftest import needs_sandbox
from tests.kit.reallab import CTX, RealLab, real_lab
from tests.unit.common.twin.test_sensor_gap import HIDDEN
from tests.unit.common.twin.test_twin_store import DAY, FITTED_AT, calibration
from viewers.web.replay import ReplayFeed

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

SLOT = 2.0
TINY = b"""\
from common.controller import Controller, Khepera


class Ahead(Controller):
    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(6, 6)
"""


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("reclab")), agents=True, slot=SLOT) as env:
        yield env


def test_my_slot_is_listed_in_my_recordings_and_replays(open_page, lab: RealLab) -> None:
    alice = open_page("alice")
    panel = enter_arena(alice, lab, "alice")
    recordings = panel.recordings
    assert recordings is not None
    pick_robot(alice, panel, "k0")
    upload(alice, "ahead.py", TINY)
    alice.wait_text("Your controller on k0 finished", timeout=30_000)  # the slot ran out

    folder = alice.p.get_by_text("Recordings", exact=True).first
    settle(folder)
    folder.click()

    # The context writes the file (and its summary) 1.5 s after the slot's end; alice
    # presses Refresh until her table (markdown, drawn as an HTML table) shows the run.
    table = alice.p.locator("table").filter(has_text="finished")

    def listed() -> bool:
        alice.click("Refresh")
        try:
            table.first.wait_for(timeout=2_000)
        except PlaywrightTimeout:
            return False
        return True

    wait_until(listed, 30, what=lambda: f"her run in her table; listed: {recordings._entries}")
    entry = recordings._entries[0]
    assert entry.agent == "k0" and entry.status == "finished"
    assert entry.duration_s is not None and entry.duration_s > 1.0
    expect(table.first.get_by_role("cell", name="k0", exact=True)).to_be_visible()
    # Download: the notice's link names the whole file, not cut off.
    alice.click("Download")
    link = alice.p.locator(f'a[download="{entry.name}.mcap"]')
    link.wait_for(timeout=15_000)
    label = link.locator(".mantine-Button-label")
    assert entry.name in label.inner_text()
    assert label.evaluate("e => e.scrollWidth <= e.clientWidth && e.scrollHeight <= e.clientHeight")
    alice.click("Replay")
    view = session_of(lab.viewer, "alice").view
    wait_until(lambda: isinstance(view.feed, ReplayFeed), 15, what="the replay in alice's view")
    wait_until(lambda: view.drawn is not None, 10, what="a recorded frame drawn")
    alice.screenshot("real-recording-replay")
    alice.click("Back to live")
    wait_until(lambda: not isinstance(view.feed, ReplayFeed), 15, what="the live arena again")
    # A simulated run has no camera: calibrating from it is refused, in words that say why.
    alice.click("Calibrate the robot (twin)")
    alice.wait_text(f"{entry.name} cannot calibrate k0", timeout=15_000)
    alice.wait_text("calibrating needs the arena camera's view of the robot")
    # Keeping a fitted twin is the arena's owner's (ida's): alice is never offered it. This
    # lab's robots are simulated (no camera, no fit), so the fit is handed to each panel as
    # a real run's would be; the keeping goes through the page and the real registry.
    fitted = ("k0", calibration("k0").to_json("ida", FITTED_AT))
    recordings._offer(fitted)
    assert not recordings.keep.visible
    expect(alice.p.get_by_role("button", name="Keep as k0's twin")).to_have_count(0)
    ida = open_page("ida")
    owned = enter_arena(ida, lab, "ida").recordings
    assert owned is not None and owned.owner
    folder = ida.p.get_by_text("Recordings", exact=True).first
    settle(folder)
    folder.click()
    # A real run's fit, as the page shows it: here a rehearsal of the dance on the emulated
    # body, whose sensor 3 reads 1.3 times the datasheet's curve (a real arena's recording).
    owned.show_calibration("dance", "k1", rehearse(HIDDEN, seed=3))
    ida.wait_text("k1's twin from dance")
    ida.wait_text("sensor error on dance, median |model - recorded| (counts)")
    shown = owned.details.content.replace("\\", "")  # the markdown's escapes
    ir = re.search(r"- datasheet: ([-0-9 /]+)\n- k1's twin fitted [^:]+: ([-0-9 /]+)", shown)
    assert ir is not None, shown
    assert float(ir.group(1).split(" / ")[3]) > 3 * float(ir.group(2).split(" / ")[3]), shown
    owned._offer(fitted)
    ida.click("Keep as k0's twin")
    # Kept for this arena's k0 (another arena's k0 is another robot).
    ida.wait_text(f"Kept k0's twin fitted {DAY} by ida as k0's twin in {CTX} v1 (in force).")
    ida.screenshot("real-recording-keep-twin")
    with lab.lab.client("ida") as client:
        kept = client.twins.of("k0", CTX).current
    assert kept is not None and kept.version == 1 and kept.saved_by == "ida"
