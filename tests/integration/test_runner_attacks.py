"""Hostile uploads through the real lab: registry, engine, runner and agent
context as processes, the runner's sandbox as in production.

What a student or an admin would check: every slot ends on time, the
student is told why a run was ended, the runner process stays small, and it
runs the next upload as usual.
"""

from __future__ import annotations

import textwrap
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from types import SimpleNamespace

import psutil
import pytest

from common.client.agent_client import FINAL
from common.messages import RunAccepted, RunRequest
from common.service import RequestError, close_session, open_session
from services.runner.service import MAX_RUNS_PER_USER, RunnerService
from tests.conftest import Procs, Router, needs_sandbox
from tests.kit.agentkit import (
    agent_user,
    start_agent_lab,
)
from tests.kit.lab import ProcessLab, make_lab

pytestmark = needs_sandbox
CONTROLLERS = Path(__file__).with_name("controllers")
HEADER = "from common.controller import Controller, Khepera\n"
# Long enough for the filler to reach the disk limit inside its slot on a busy machine
# (at 2.5 s a fresh-clone run saw its slot end first: "its slot ended", not the limit).
SLOT = 5.0
# Stands in for the runner's login where only its RunClaim is sealed with it.
_CLAIM_SEALER = SimpleNamespace(session=SimpleNamespace(seal=lambda key, message: b"sealed"))
MB = 1 << 20

STALLED = """
import os, signal
class Frozen(Controller):
    def initialize(self, robot):
        os.kill(os.getpid(), signal.SIGSTOP)
    def do_work(self, robot):
        pass
"""
FLOOD = """
import sys
class Flood(Controller):
    def do_work(self, robot):
        chunk = "x" * (1 << 20)
        while True:
            sys.stdout.write(chunk)
"""
FILES = """
class Filler(Controller):
    def do_work(self, robot):
        for i in range(1200):
            with open(f"/work/f{i}", "wb") as f:
                f.write(b"z" * (1 << 20))
"""


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    _, lab.runner, _ = start_agent_lab(lab, slot=SLOT)
    yield lab


def test_stalled_flooding_and_filling_uploads_end_on_time_and_say_why(lab: ProcessLab) -> None:
    runner = psutil.Process(lab.runner.popen.pid)  # type: ignore[attr-defined]
    before = runner.memory_info().rss
    attacks = {"stalled": ("bob", "k0", STALLED), "flood": ("carol", "k1", FLOOD)}
    attacks["files"] = ("ida", "k2", FILES)
    with agent_user(lab, "alice") as watcher, ExitStack() as users:
        rids: dict[str, str] = {}
        queued = time.monotonic()
        for name, (user, agent, body) in attacks.items():
            # each student stays: a student who leaves has their runs cancelled
            client = users.enter_context(agent_user(lab, user))
            source = textwrap.dedent(HEADER + body).encode()
            rids[name] = client.queue(agent, "deploy", source=source).request_id
        took: dict[str, float] = {}
        reasons: dict[str, str] = {}
        for name, rid in rids.items():
            running = watcher.wait_status(rid, {"running"}, timeout=20)
            assert running is not None, f"{name} never ran"
            final = watcher.wait_status(rid, FINAL, timeout=SLOT + 15)
            assert final is not None, f"{name} outlived its slot"
            took[name], reasons[name] = time.monotonic() - queued, final.reason
        # from the upload, so with the start-up of three sandboxes: a generous bound
        assert all(t < SLOT + 5.0 for t in took.values()), took
        assert reasons["stalled"] == "its slot ended", reasons
        assert "output flood" in reasons["flood"], reasons
        assert "out of disk space" in reasons["files"], reasons
        grown = runner.memory_info().rss - before
        assert grown < 60 * MB, f"the runner grew by {grown / MB:.0f} MB"
        assert runner.is_running()
        # and it runs the next upload as usual
        talker = watcher.queue("k3", "deploy", source=(CONTROLLERS / "talker.py").read_bytes())
        assert watcher.wait_status(talker.request_id, {"running"}, timeout=15) is not None
        final = watcher.wait_status(talker.request_id, FINAL, timeout=SLOT + 15)
        assert final is not None and final.status == "finished", final


def test_one_user_cannot_take_every_place_on_a_runner(router: Router) -> None:
    sleeper = textwrap.dedent(
        HEADER
        + """
import time
class Sleeper(Controller):
    def do_work(self, robot):
        time.sleep(60)
"""
    ).encode()
    session = open_session(router.options(), wait=10.0)
    runner = RunnerService(
        session,
        router.realm,
        "runner",
        registry_key=bytes(32),
        login=_CLAIM_SEALER,  # type: ignore[arg-type]
    )

    def request(n: int, user: str) -> RunRequest:
        return RunRequest(
            request_id=f"r{n}",
            ctx="arena",
            world="arena",
            agent=f"k{n}",
            user=user,
            source=sleeper,
            end=time.time() + 30,
        )

    try:
        for n in range(MAX_RUNS_PER_USER):
            assert isinstance(runner._start(request(n, "mallory")), RunAccepted)
        with pytest.raises(RequestError, match="mallory already runs 4 controllers"):
            runner._start(request(9, "mallory"))
        assert isinstance(runner._start(request(10, "alice")), RunAccepted)
    finally:
        runner.on_stop(10.0)
        close_session(session)
    assert runner.runs() == []
