"""A teacher takes a student's running robot over in the page, drives it, hands it back.

Chromium against a real lab (router, registry, engine with a service identity,
runner, agent context ``arena`` owned by ida). The student's controller is
queued by a client; the student's page says what happens to it. Screenshots
are kept in test-artifacts/.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from tests.browser.conftest import wait_until
from tests.browser.test_real_agents import enter_arena, pick_robot
from tests.conftest import needs_sandbox
from tests.kit.agentkit import Motion, agent_user
from tests.kit.reallab import RealLab, real_lab

pytestmark = [pytest.mark.integration, needs_sandbox, pytest.mark.real_lab]

FORWARD = (Path(__file__).parents[1] / "integration" / "controllers" / "forward.py").read_bytes()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("takeover")), agents=True, slot=300.0) as env:
        yield env


def test_the_teacher_takes_over_in_the_page_and_hands_back(open_page, lab: RealLab) -> None:
    ida, alice = open_page("ida"), open_page("alice")
    ida_panel = enter_arena(ida, lab, "ida")
    alice_panel = enter_arena(alice, lab, "alice")
    teacher, student = ida_panel.robots, alice_panel.robots
    assert teacher is not None and student is not None
    wait_until(lambda: teacher.takeover.visible, 10, what="ida's take-over buttons")
    assert not student.takeover.visible  # a student never sees them

    motion = Motion(lab.session, lab.router.realm)
    with agent_user(lab.lab, "alice") as al:
        rid = al.queue("k1", "deploy", source=FORWARD, filename="forward.py").request_id
        assert al.wait_status(rid, {"running"}, timeout=60), "alice's controller never ran"
        wait_until(lambda: motion.moving(["k1"], 0.0), 30, what="alice's controller driving")

        pick_robot(ida, ida_panel, "k1")
        taken = time.monotonic()
        ida.click("Take over the chosen robot")
        ida.wait_text("k1 taken over from alice: their controller is paused")
        ida.wait_text("taken over by ida")  # the robots' table
        alice.wait_text("your robot is driven by ida since", timeout=15_000)
        alice.wait_text("k1: your controller is paused: a teacher took the robot over")
        wait_until(lambda: motion.at_rest_since(["k1"], taken), 20, what="k1 paused at rest")
        alice.screenshot("takeover-student-view")

        driving = time.monotonic()
        ida.click("Reverse")
        wait_until(lambda: motion.moving(["k1"], driving), 20, what="k1 driven from the page")
        ida.screenshot("takeover-teacher-driving")
        stopped = time.monotonic()
        ida.click("Stop driving")
        wait_until(lambda: motion.at_rest_since(["k1"], stopped), 20, what="k1 stopped")

        ida.click("Hand back")
        ida.wait_text("k1 handed back to alice's controller")
        alice.wait_text("ida handed your robot back: your controller drives again", 15_000)
        alice.wait_text("k1: your controller drives again: the robot was handed back")
        resumed = time.monotonic()
        wait_until(lambda: motion.moving(["k1"], resumed), 20, what="alice's controller again")
        assert al.wait_status(rid, FINAL, timeout=0.2) is None  # the same slot goes on
        al.cancel(rid)
    motion.close()
