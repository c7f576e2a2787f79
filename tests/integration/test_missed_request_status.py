"""A client that missed its request's last event asks the context, and is told the truth.

The context publishes a request's end once. Here that one message never
reaches the client (dropped in the client, or the client was not listening
yet), the runner is killed mid-slot, and the student must still read the
real reason ("the lab's runner runner stopped"), never "lost".
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.agent_client import FINAL, AgentClient
from common.lab_errors import NotAllowed
from common.messages import AgentEvent
from services.commands import deploy
from services.context.agent_context import RUNNER_CHECK_S
from tests.conftest import Proc, Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    agent_user,
    start_agent_context,
    start_agent_lab,
)
from tests.kit.lab import PASSWORD, ProcessLab, make_lab

pytestmark = [pytest.mark.one_worker, needs_sandbox, pytest.mark.shared_router]
FORWARD = Path(__file__).with_name("controllers") / "forward.py"
RUNNER_STOPPED = "the lab's runner runner stopped"


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[tuple[ProcessLab, Proc, Proc]]:
    """A lab whose slots outlast the test (30 s): a request ends only when made to."""
    lab = make_lab(router, procs, tmp_path)
    _, runner, context = start_agent_lab(lab, slot=30.0)
    yield lab, runner, context


def _bobs_deploy_killing_mid_slot(lab: ProcessLab, victim: Proc) -> tuple[int, list[BaseException]]:
    """Bob's ``wart deploy`` of FORWARD on k3, in this process, with ``victim`` killed once
    bob's slot starts: deploy's exit code, and what failed in the killing thread."""
    failures: list[BaseException] = []

    with agent_user(lab, "ida") as ida:

        def kill_mid_slot() -> None:
            try:
                wait_for(lambda: ida.position_of_user("bob", "k3") == 0, 60, "bob's slot")
                victim.kill9()
            except BaseException as exc:  # seen by the test, not lost in the thread
                failures.append(exc)

        killer = threading.Thread(target=kill_mid_slot, daemon=True)
        killer.start()
        argv = [str(FORWARD), "--context", "arena", "--agent", "k3", "--user", "bob"]
        code = deploy.main([*argv, *lab.net_args()])
        killer.join(5)
    return code, failures


def test_wart_deploy_that_misses_the_end_still_prints_the_real_reason(
    lab: tuple[ProcessLab, Proc, Proc],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    the_lab, runner, _ = lab
    receive = AgentClient._on_event

    def drop_bobs_ends(self: AgentClient, event: AgentEvent) -> None:
        # The one message that says how bob's request ended never arrives; the queue
        # states (showing it gone) still do, as in the chaos test that saw "lost".
        if self.client.user == "bob" and event.request and event.request.status in FINAL:
            return
        receive(self, event)

    monkeypatch.setattr(AgentClient, "_on_event", drop_bobs_ends)
    monkeypatch.setattr(deploy, "interrupt_event", threading.Event)  # pytest keeps its signals
    monkeypatch.setenv("WART_PASSWORD", PASSWORD)
    code, failures = _bobs_deploy_killing_mid_slot(the_lab, runner)
    out = capsys.readouterr().out
    assert not failures, failures
    assert code == 1, out
    assert "running on k3" in out
    last = out.strip().splitlines()[-1]
    assert last.startswith(f"cancelled: {RUNNER_STOPPED}"), out
    assert "lost" not in out, out


def test_a_late_client_asks_how_its_request_ended_even_across_a_context_restart(
    lab: tuple[ProcessLab, Proc, Proc],
) -> None:
    the_lab, runner, context = lab
    # Her first client stays joined (leaving would end the request) but is not the one
    # that asks: a second session of hers joins only after the end, as a restarted
    # `wart deploy` or a reloaded web page would.
    with agent_user(the_lab, "alice") as first, agent_user(the_lab, "ida") as ida:
        queued = first.queue("k2", "deploy", source=FORWARD.read_bytes(), filename="forward.py")
        rid = queued.request_id
        assert first.wait_status(rid, {"running"}, timeout=60), first.statuses(rid)
        runner.kill9()

        def ended() -> bool:
            # Asked of the context, not read off ida's queue view: a view she has not
            # received yet also shows no position (that once passed at once).
            time.sleep(0.25)
            reply = ida.request_status(rid)
            return reply is not None and reply.ended

        # The context asks the runner what it still runs for up to RUNNER_CHECK_S
        # before taking its silence for its death.
        wait_for(ended, RUNNER_CHECK_S + 15, "the end of the run")

        def asked(user: str) -> str:
            with agent_user(the_lab, user) as late:
                assert late.statuses(rid) == []  # it never heard of the end
                reply = late.request_status(rid)
            assert reply is not None and reply.status is not None, reply
            assert reply.ended and reply.status.status == "cancelled", reply
            assert reply.status.user == "alice" and reply.status.agent == "k2"
            return reply.status.reason

        assert asked("alice").startswith(RUNNER_STOPPED)  # a new session of hers
        assert asked("ida").startswith(RUNNER_STOPPED)  # the context's owner: anyone's
        with agent_user(the_lab, "bob") as bob, pytest.raises(NotAllowed, match="alice's"):
            bob.request_status(rid)

        # The record is kept with the queues: the context restarted still knows.
        context.stop()
        context = start_agent_context(the_lab, slot=30.0)
        assert asked("alice").startswith(RUNNER_STOPPED)
        unknown = ida.request_status("k2-999-abcdef")
        assert unknown is not None and not unknown.known
        context.kill9()
        assert ida.request_status(rid) is None  # the context down: no answer, not "lost"


def test_wart_deploy_says_the_context_is_down_rather_than_lost(
    lab: tuple[ProcessLab, Proc, Proc],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    the_lab, _, context = lab
    # Sooner than a student's minute, or the test would wait it out.
    monkeypatch.setattr(deploy, "SILENT_AFTER_S", 1.0)
    monkeypatch.setattr(deploy, "CONTEXT_DOWN_GIVE_UP_S", 3.0)
    monkeypatch.setattr(deploy, "interrupt_event", threading.Event)
    monkeypatch.setenv("WART_PASSWORD", PASSWORD)
    code, failures = _bobs_deploy_killing_mid_slot(the_lab, context)
    out = capsys.readouterr().out
    assert not failures, failures
    assert code == 1, out
    assert "the arena arena is not answering (stopped or restarting?)" in out, out
    assert (
        out.strip()
        .splitlines()[-1]
        .startswith("the arena arena has not answered for 3 s: it is down")
    ), out
    assert "lost" not in out, out
