"""A teacher takes over a student's running robot and hands it back (issue 36 item 6, aseba #307).

Registry, engine (a service identity: MAC leases, as under ``wart up``), runner
and agent context are real ``wart`` processes; the student, the teacher and
another student are AgentClients here, and ``wart arena takeover`` a real process.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL
from common.controller import Khepera
from common.lab_errors import LabError
from common.messages import AuditQuery, RequestStatus
from common.recording import read_recording
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    CTX,
    WORLD,
    Motion,
    agent_user,
    agent_users,
    start_agent_lab,
    start_deploy,
)
from tests.kit.lab import PASSWORD, ProcessLab, make_lab
from tests.kit.procs import Proc

pytestmark = needs_sandbox
CONTROLLERS = Path(__file__).with_name("controllers")
FORWARD = (CONTROLLERS / "forward.py").read_bytes()
REVERSE = """\
from common.controller import Controller, Khepera


class Reverse(Controller):
    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(-10, -10)
"""


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    start_agent_lab(lab, identity=True, slot=120.0)
    yield lab


def _steps(alice_sees: list[RequestStatus]) -> list[str]:
    return [s.takeover for s in alice_sees if s.takeover is not None]


def test_a_teacher_takes_over_a_running_robot_drives_it_and_hands_it_back(
    lab: ProcessLab, tmp_path: Path
) -> None:
    with (
        lab.zsession() as z,
        agent_users(lab, "alice", "bob", "ida") as (alice, bob, ida),
    ):
        seen: list[RequestStatus] = []
        alice.on_status = seen.append
        motion = Motion(z, lab.router.realm)
        queued = alice.queue("k1", "deploy", source=FORWARD, filename="forward.py")
        rid = queued.request_id
        assert alice.wait_status(rid, {"running"}, timeout=60), "alice's controller never ran"
        wait_for(lambda: motion.moving(["k1"], 0.0), 30, "alice's controller to drive k1")

        # Refusals, with their reasons: a student, and a robot where nothing runs.
        with pytest.raises(LabError, match="only the owner of arena or a user with 'kick'"):
            bob.take_over("k1", "my turn")
        with pytest.raises(LabError, match="nothing runs on k2"):
            ida.take_over("k2")
        with pytest.raises(LabError, match="k1 is not taken over"):
            ida.hand_back("k1")

        # Taken: alice's controller runs on, paused; its commands no longer move k1.
        taken = ida.take_over("k1", "it keeps hitting the wall")
        assert (taken.user, taken.request_id, taken.world) == ("alice", rid, WORLD)
        wait_for(lambda: _steps(seen) == ["taken"], 10, "alice to be told of the take-over")
        told = next(s for s in seen if s.takeover == "taken")
        assert told.status == "running" and told.taken_by == "ida"
        assert told.reason.startswith("your robot is driven by ida since ")
        assert "your controller is paused (it keeps hitting the wall)" in told.reason
        entry = alice.state().agents[1].entries[0]
        assert (entry.request_id, entry.taken_by) == (rid, "ida")
        paused_at = time.monotonic()
        wait_for(lambda: motion.at_rest_since(["k1"], paused_at), 20, "k1 at rest while taken")
        assert alice.wait_status(rid, FINAL, timeout=0.5) is None  # paused, not ended

        # The teacher drives: k1 moves under ida's commands.
        link = ida.robot_link(WORLD, "k1")
        robot = Khepera(link)
        driving = time.monotonic()

        def drives() -> bool:
            robot.set_speeds(-10, -10)  # backwards, where alice's drove forwards
            return motion.moving(["k1"], driving)

        wait_for(drives, 20, "ida's commands to move k1")
        robot.set_speeds(0, 0)
        link.close(stop=True)

        # Handed back: alice's controller drives again, in the same slot.
        detail = ida.hand_back("k1")
        assert "handed back to alice's controller" in detail
        wait_for(
            lambda: _steps(seen) == ["taken", "handed_back"], 10, "alice told of the hand-back"
        )
        back = next(s for s in seen if s.takeover == "handed_back")
        assert back.reason == "ida handed your robot back: your controller drives again"
        resumed = time.monotonic()
        wait_for(lambda: motion.moving(["k1"], resumed), 20, "alice's controller to drive again")
        assert alice.state().agents[1].entries[0].taken_by is None
        assert alice.wait_status(rid, FINAL, timeout=0.2) is None

        # A teacher who leaves the context while holding the robot gives it back.
        ida.take_over("k1")
        ida.leave()
        wait_for(lambda: len(_steps(seen)) == 4, 10, "the hand-back of a teacher who left")
        assert seen[-1].reason == "ida went away (left the context): your controller drives again"
        alice.cancel(rid)
        assert alice.wait_status(rid, FINAL, timeout=20) is not None
        motion.close()

    # The run's recording says each step, and has ida's commands as hers.
    path = lab.state / "rooms" / "recordings" / CTX / "alice" / f"{rid}.mcap"
    wait_for(path.with_name(f"{rid}.summary.json").exists, 20, "the run's recording")
    rec = read_recording(path)
    kinds = [e.record.kind for e in rec.events if e.record.request_id == rid]
    assert kinds.index("started") < kinds.index("taken") < kinds.index("handed_back")
    senders = {c.record.sender for c in rec.commands}
    assert "ida" in senders and len(senders) == 2, senders  # ida's and the runner's

    # The audit trail: the take-over and the hand-back, and bob's refusal.
    with lab.client("admin") as admin:

        def trail(action: str) -> list[tuple[str, str]]:
            entries, _ = admin.audit_trail(AuditQuery(action=action))
            return sorted((e.actor, e.outcome) for e in entries)

        handbacks = [("ida", "ok"), ("ida", "ok"), ("ida", "refused")]  # by hand, and on leaving
        wait_for(lambda: trail("handback") == handbacks, 10, "the audit trail's hand-backs")
        takes = [("bob", "refused"), ("ida", "ok"), ("ida", "ok"), ("ida", "refused")]  # k2: idle
        assert trail("takeover") == takes


def test_wart_arena_takeover_holds_or_drives_the_robot_until_ctrl_c_and_hands_it_back(
    lab: ProcessLab, procs: Procs, tmp_path: Path
) -> None:
    def arena(verb: str, user: str, *extra: str) -> Proc:
        args = ["arena", *lab.net_args(), verb, "k1", "--context", CTX, "--user", user, *extra]
        return procs.start(f"arena-{verb}-{user}", args, env={"WART_PASSWORD": PASSWORD})

    with agent_user(lab, "alice") as alice:
        seen: list[RequestStatus] = []
        alice.on_status = seen.append
        # Her controller uploaded with wart deploy, which tells her of each step.
        deploy = start_deploy(lab, CONTROLLERS / "forward.py", "k1", "alice")
        wait_for(lambda: alice.statuses_of_user("alice"), 60, "her request in the queue state")
        rid = alice.statuses_of_user("alice")[0]
        assert alice.wait_status(rid, {"running"}, timeout=60)

        refused = arena("takeover", "bob")
        assert refused.popen.wait(60) == 1
        assert "only the owner of arena or a user with 'kick'" in refused.output()

        holding = arena("takeover", "ida", "--reason", "demo")
        wait_for(lambda: _steps(seen) == ["taken"], 30, "the take-over by wart arena")
        wait_for(lambda: "holding it still" in holding.output(), 10, "its words")
        holding.popen.send_signal(signal.SIGINT)  # Ctrl-C
        assert holding.popen.wait(30) == 0, holding.output()
        wait_for(lambda: _steps(seen) == ["taken", "handed_back"], 10, "the hand-back")
        assert "handed back to alice's controller" in holding.output()
        assert alice.wait_status(rid, FINAL, timeout=0.2) is None  # her run goes on
        wait_for(lambda: "ida handed your robot back" in deploy.output(), 10, "wart deploy's words")
        assert "your robot is driven by ida since " in deploy.output()
        assert "your controller is paused (demo)" in deploy.output()

        # The teacher's own controller, run on the teacher's machine, drives k1.
        reverse = tmp_path / "reverse.py"
        reverse.write_text(REVERSE)
        with lab.zsession() as z:
            motion = Motion(z, lab.router.realm)
            driving = arena("takeover", "ida", "--controller", str(reverse))
            wait_for(lambda: _steps(seen) == ["taken", "handed_back", "taken"], 30, "taken again")
            wait_for(lambda: "driving it with reverse.py" in driving.output(), 10, "its words")
            since = time.monotonic()
            wait_for(lambda: motion.moving(["k1"], since), 20, "ida's controller to drive k1")
            driving.popen.send_signal(signal.SIGINT)
            assert driving.popen.wait(30) == 0, driving.output()
            wait_for(lambda: _steps(seen)[-1] == "handed_back", 10, "handed back again")
            assert "steps driven" in driving.output()
            motion.close()
        assert alice.wait_status(rid, FINAL, timeout=0.2) is None
