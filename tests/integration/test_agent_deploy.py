"""Deployed controllers through the agent context and the runner, with real processes."""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from common import keys
from common.client.agent_client import FINAL
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import OutputLines, RequestStatus
from tests.conftest import Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    Poses,
    agent_user,
    start_agent_lab,
    start_deploy,
)
from tests.kit.lab import ProcessLab, module_lab

pytestmark = [pytest.mark.one_worker, needs_sandbox]
CONTROLLERS = Path(__file__).with_name("controllers")
HEADER = "from common.controller import Controller, Khepera\n"


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    """One lab for the module: each test's requests have ended when it returns, so the
    next finds every queue empty (the hostile test queues on all four robots at once)."""
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        start_agent_lab(lab)
        yield lab


def test_wart_deploy_runs_the_upload_and_shows_its_output(lab: ProcessLab) -> None:
    with lab.zsession() as z:
        poses = Poses(z, lab.router.realm)
        start = poses.xy("k3")
        proc = start_deploy(lab, CONTROLLERS / "talker.py", "k3", "bob")
        assert proc.popen.wait(30) == 0, proc.output()
        out = proc.output()
        assert "uploaded talker.py" in out
        assert "[k3] hello from the sandbox" in out
        assert "[k3] front" in out
        assert "finished: " in out
        assert float(np.linalg.norm(poses.xy("k3") - start)) > 20, "the upload drove k3"


def test_bad_uploads_are_refused_before_they_queue(lab: ProcessLab) -> None:
    with agent_user(lab, "alice") as alice:
        with pytest.raises(LabError, match="line 1: syntax error"):
            alice.queue("k0", "deploy", source=b"def (:\n")
        with pytest.raises(LabError, match="defines no controller"):
            alice.queue("k0", "deploy", source=b"x = 1\n")
        with pytest.raises(LabError, match="no agent zz"):
            alice.queue("zz", "deploy", source=(CONTROLLERS / "talker.py").read_bytes())
        with pytest.raises(LabError, match=r"bad_request|not a valid|64"):
            alice.queue("k0", "deploy", source=b"#" * (70 * 1024))


HOSTILE = {
    "loop": """
class Spin(Controller):
    def do_work(self, robot):
        while True:
            pass
""",
    "memory": """
class Hog(Controller):
    def do_work(self, robot):
        hoard = []
        while True:
            hoard.append(bytearray(50 * 1024 * 1024))
""",
    "fork": """
import os
class Forker(Controller):
    def do_work(self, robot):
        while True:
            try:
                os.fork()
            except OSError as exc:
                print("fork refused:", exc)
                break
""",
    "files": """
class Snoop(Controller):
    def do_work(self, robot):
        for path in ("/etc/shadow", "/root/.ssh/id_rsa", "/home", "../../etc/passwd"):
            try:
                print(path, "read", len(open(path).read()))
            except Exception as exc:
                print(path, "refused", type(exc).__name__)
        robot.set_speeds(0, 0)
""",
    "socket": """
import socket
class Net(Controller):
    def do_work(self, robot):
        try:
            socket.create_connection(("127.0.0.1", 7447), timeout=1)
            print("socket connected")
        except OSError as exc:
            print("socket refused", type(exc).__name__)
        robot.set_speeds(0, 0)
""",
}


def test_hostile_uploads_are_contained_and_everything_keeps_serving(lab: ProcessLab) -> None:
    outputs: dict[str, list[str]] = {}

    def collect(out: OutputLines) -> None:
        outputs.setdefault(out.request_id, []).extend(out.lines)

    agents = ["k0", "k1", "k2", "k3", "k0"]
    users = ["alice", "bob", "carol", "ida", "bob"]
    with agent_user(lab, "alice") as watcher:
        watcher.on_output = collect
        requests: dict[str, str] = {}
        clients = []
        for (name, body), agent, user in zip(HOSTILE.items(), agents, users, strict=True):
            cm = agent_user(lab, user)
            client = cm.__enter__()
            clients.append(cm)
            source = textwrap.dedent(HEADER + body).encode()
            requests[name] = client.queue(agent, "deploy", source=source).request_id
        try:
            ended: dict[str, RequestStatus] = {}
            for name, rid in requests.items():
                status = watcher.wait_status(rid, FINAL, timeout=30)
                assert status is not None, f"{name} never ended"
                assert status.status == "finished", (name, status)
                ended[name] = status

            def printed(name: str) -> str:
                return "\n".join(outputs.get(requests[name], []))

            # The printed lines travel on their own key: the last of them may land after the
            # run's final status on a loaded machine.
            # The hog is stopped whichever comes first: out of memory; on a machine so busy
            # that filling its memory takes longer than a step may, as hung; or by the end
            # of its 2.5 s slot, the backstop for every run (once, in a fresh-clone run at
            # load 14, before either).
            hog = ended["memory"].reason
            stopped = ("out of memory" in hog, hog.startswith("hung: do_work"))
            assert any(stopped) or hog == "its slot ended", hog
            if "out of memory" in hog:
                try:
                    wait_for(lambda: "MemoryError" in printed("memory"), 15, "its MemoryError")
                except AssertionError as exc:
                    raise AssertionError(f"{exc}; its lines: {printed('memory')!r}") from None
            wait_for(lambda: "socket refused" in printed("socket"), 15, "'socket refused'")
            text = {name: printed(name) for name in requests}
            assert "read" not in text["files"].replace("refused", ""), text["files"]
            assert "socket refused" in text["socket"], text["socket"]
            assert "socket connected" not in text["socket"]
        finally:
            for cm in reversed(clients):
                cm.__exit__(None, None, None)
        # the context, the engine and the runner still serve
        state = watcher.state()
        assert {line.agent for line in state.agents} == {"k0", "k1", "k2", "k3"}
        with lab.zsession() as z:
            poses = Poses(z, lab.router.realm)
            assert poses.count > 0
            alive = [
                str(r.ok.key_expr)
                for r in z.liveliness().get(keys.alive_of_kind(lab.router.realm, AliveKind.RUNNER))
                if r.ok is not None
            ]
            assert alive, "the runner is still alive"
        rid = watcher.queue("k1", "deploy", source=(CONTROLLERS / "talker.py").read_bytes())
        status = watcher.wait_status(rid.request_id, {"running"}, timeout=15)
        assert status is not None
        wait_for(lambda: any("hello" in x for x in outputs.get(rid.request_id, [])), 15, "output")
        watcher.cancel(rid.request_id)
        final = watcher.wait_status(rid.request_id, FINAL, timeout=10)
        assert final is not None and final.status == "cancelled"


def test_one_example_drives_unchanged_in_both_run_modes(lab: ProcessLab) -> None:

    from common.controller import load_controller

    path = Path(__file__).resolve().parents[2] / "examples" / "01_braitenberg.py"
    with lab.zsession() as z, agent_user(lab, "alice") as alice:
        poses = Poses(z, lab.router.realm)
        # remote: the controller runs in this process, over Zenoh
        start = poses.xy("k1")
        result = alice.drive("k1", load_controller(path))
        assert result.status == "finished" and result.iterations > 20, result
        remote = float(np.linalg.norm(poses.xy("k1") - start))
        # deploy: the same file, uploaded, run by the runner in its sandbox
        start = poses.xy("k1")
        queued = alice.queue("k1", "deploy", source=path.read_bytes(), filename=path.name)
        final = alice.wait_status(queued.request_id, FINAL, timeout=20)
        assert final is not None and final.status == "finished", final
        deployed = float(np.linalg.norm(poses.xy("k1") - start))
        assert remote > 50 and deployed > 50, (remote, deployed)


COUNTER = HEADER + textwrap.dedent(
    """
    class Counter(Controller):
        period = 0.1  # 4 lines a step: under the sandbox's 50 lines a second
        printed = 0

        def do_work(self, robot: Khepera) -> None:
            for _ in range(4 if self.printed < 60 else 0):
                print("line", self.printed)
                self.printed += 1
    """
)


def test_a_page_that_comes_late_reads_the_runs_output_so_far_in_the_events_count(
    lab: ProcessLab,
) -> None:
    events: list[OutputLines] = []
    with agent_user(lab, "alice") as alice:
        alice.on_output = events.append
        rid = alice.queue("k2", "deploy", source=COUNTER.encode()).request_id

        def printed() -> list[str]:
            return [line for e in list(events) if e.request_id == rid for line in e.lines]

        wait_for(lambda: "line 59" in printed(), 30, "its 60 lines in the events")
        mine, lines = [e for e in events if e.request_id == rid], printed()
        # The context numbers the lines: each event says how many came before it.
        assert [e.first for e in mine] == [sum(len(m.lines) for m in mine[:i]) for i in
                                           range(len(mine))]  # fmt: skip
        # Another session of hers (a second tab) asks what it missed: all of it, in order.
        with agent_user(lab, "alice") as tab:
            so_far = tab.output_so_far(rid)
            assert (so_far.agent, so_far.user, so_far.first) == ("k2", "alice", 0)
            assert so_far.lines == lines and lines[-1] == "line 59"
            with pytest.raises(LabError, match="no request k2-9-000000 here"):
                tab.output_so_far("k2-9-000000")
        final = alice.wait_status(rid, FINAL, timeout=15)
        assert final is not None and final.status == "finished"
        # After its end too, and for whoever may join the arena (its events showed them all).
        with agent_user(lab, "bob") as bob:
            assert bob.output_so_far(rid).lines[: len(lines)] == lines
