"""The arena tab's emergency stop and dry run, in Chromium, against a real lab.

One lab for the module (router, registry, engine with a service identity,
runner, agent context ``arena`` owned by ida, slots long enough that only the
stop ends them). Screenshots are kept in test-artifacts/.
"""

from __future__ import annotations

import textwrap
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from tests.browser.conftest import ViserPage, wait_until
from tests.browser.test_real_agents import enter_arena, pick_robot
from tests.conftest import needs_sandbox
from tests.kit.agentkit import Motion, agent_user, deploy_running
from tests.kit.reallab import RealLab, real_lab

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

FORWARD = (Path(__file__).parents[1] / "integration" / "controllers" / "forward.py").read_bytes()
ROBOTS = ("k0", "k1", "k2", "k3")
INTO_THE_WALL = textwrap.dedent(
    """\
    from common.controller import Controller, Khepera


    class Charge(Controller):
        def do_work(self, robot: Khepera) -> None:
            robot.set_speeds(127, 127)
    """
).encode()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("safety")), agents=True, slot=300.0) as env:
        yield env


def dry_run_file(page: ViserPage, name: str, content: bytes) -> None:
    with page.p.expect_file_chooser() as chooser:
        page.click("Dry run (.py)")
    chooser.value.set_files({"name": name, "mimeType": "text/x-python", "buffer": content})


def test_the_dry_run_button_reports_a_controller_that_drives_into_a_wall(
    open_page, lab: RealLab
) -> None:
    alice = open_page("alice")
    panel = enter_arena(alice, lab, "alice")
    pick_robot(alice, panel, "k3")
    dry_run_file(alice, "charge.py", INTO_THE_WALL)
    alice.wait_text(
        "Dry run of charge.py on k3: will run, with a warning: 1 collision", timeout=40_000
    )
    alice.wait_text("wheel commands at top speed")
    alice.screenshot("dry-run-wall")
    assert panel.robots is not None
    assert all(not r.queue and r.holder is None for r in panel.robots._rows)  # nothing queued


def test_the_host_clicks_the_emergency_stop_and_four_robots_stop(open_page, lab: RealLab) -> None:
    ida, alice = open_page("ida"), open_page("alice")
    ida_panel = enter_arena(ida, lab, "ida")
    alice_panel = enter_arena(alice, lab, "alice")
    assert ida_panel.robots is not None and alice_panel.robots is not None
    wait_until(lambda: ida_panel.robots.estop.visible, 10, what="ida's emergency stop button")
    assert not alice_panel.robots.estop.visible  # a student never sees it
    assert (
        alice.button("Emergency stop (every robot)").count() == 0
        or not alice.button("Emergency stop (every robot)").is_visible()
    )

    motion = Motion(lab.session, lab.router.realm)
    with (
        agent_user(lab.lab, "bob") as bob,
        agent_user(lab.lab, "carol") as carol,
        agent_user(lab.lab, "alice") as al,
    ):
        owners = {"k0": bob, "k1": carol, "k2": al, "k3": bob}
        rids = deploy_running(owners, FORWARD)
        wait_until(lambda: motion.moving(ROBOTS, 0.0), 30, what="four robots driving")
        ida.screenshot("estop-before")

        pressed = time.monotonic()
        ida.click("Emergency stop (every robot)")
        ida.wait_text("emergency stop: every robot stopped, 4 controllers ended")
        ida.wait_text("emergency stop by ida: from the web page")  # the table's line
        for agent, who in owners.items():
            status = who.wait_status(rids[agent], FINAL, timeout=20)
            assert status is not None and status.reason.startswith("emergency stop by ida")
        wait_until(lambda: motion.at_rest_since(ROBOTS, pressed) is not None, 20, what="at rest")
        # Every member's page says why the controllers ended.
        alice.wait_text("controller on k2 was cancelled: emergency stop by ida", timeout=15_000)
        alice.wait_text("every robot is held until it is released")
        ida.screenshot("estop-engaged")
        alice.screenshot("estop-student-view")

        ida.click("Release the emergency stop")
        ida.wait_text("emergency stop released")
        wait_until(lambda: ida_panel.robots.estop.visible, 10, what="the stop button back")
        ida.screenshot("estop-released")
    motion.close()
