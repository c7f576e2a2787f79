"""``wart up``, as the README's first command runs it: one lab, the user's checks in turn.

The page's printed URL serves, ``wart doctor`` finds every process of the plan
alive, a killed child is restarted, and Ctrl-C leaves nothing behind. One lab
for the four (each `wart up` costs some 15 s of CPU to start): the tests run in
this order on one worker, and the last one stops it.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import urllib.request
import uuid
from collections.abc import Iterator

import psutil
import pytest
import zenoh

from common import keys
from common.messages import WorldSnapshot, decode
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.commands.doctor import up_plan
from services.commands.up import REAL_AGENT, REAL_WORLD, lab_plan, router_spec, settings_from_args
from services.lab.supervisor import AliveWatch
from tests.conftest import REPO, wait_for, wart_env
from tests.kit.lab import UpLab

pytestmark = pytest.mark.one_worker


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[UpLab]:
    realm = f"t{uuid.uuid4().hex[:10]}"
    lab = UpLab(realm=realm, state_dir=tmp_path_factory.mktemp("up") / "state").start()
    try:
        yield lab
    finally:
        lab.stop()


def expected_tokens(lab: UpLab) -> list[str]:
    args = argparse.Namespace(state_dir=lab.state_dir, port=lab.port, http_port=lab.http_port)
    settings = settings_from_args(args, NetworkOptions(realm=lab.realm))
    specs = [router_spec(settings), *lab_plan(settings)]
    return [spec.alive_key for spec in specs if spec.alive_key]


def test_up_prints_the_viewer_url_and_it_serves(lab: UpLab) -> None:
    line = lab.wait_line("web viewer:", timeout=120)
    match = re.search(r"http://\S+", line)
    assert match, line
    assert match.group(0).endswith(f":{lab.http_port}")
    with urllib.request.urlopen(match.group(0), timeout=10) as reply:
        assert reply.status == 200


def test_the_doctor_finds_nothing_missing_in_a_healthy_up_lab(lab: UpLab) -> None:
    lab.wait_line("The lab is running", timeout=120)
    doctor = subprocess.run(
        [sys.executable, "-m", "services.cli", "doctor", "--realm", lab.realm],
        cwd=REPO,
        env=wart_env({"WART_CONNECT": lab.endpoint}),
        capture_output=True,
        text=True,
        timeout=60,
    )
    out = doctor.stdout + doctor.stderr
    # What a user sees: every service of the plan alive, none reported missing.
    assert doctor.returncode == 0, out
    assert "no problem found" in out and "✗" not in out, out
    plan = up_plan(NetworkOptions(realm=lab.realm))
    for what, _key in plan:
        assert f"✓ {what} is alive" in out, out
    # The names the old hand-written copy got wrong: the engine's context, the viewer's id.
    assert {"agent context arena", "viewer", "bridge real1"} <= {w for w, _ in plan}


def test_lab_comes_up_restarts_a_killed_child_and_stops_cleanly(lab: UpLab) -> None:
    lab.wait_line("The lab is running", timeout=120)
    session = open_session(NetworkOptions(realm=lab.realm, connect=(lab.endpoint,)), wait=10)
    watch = AliveWatch(session, keys.alive_all(lab.realm))
    try:
        for key in expected_tokens(lab):
            assert watch.wait(key, 20), f"{key} never appeared:\n" + "\n".join(lab.lines)
        # The real-robot path without hardware: the bridge has the emulated Khepera online.
        wait_for(
            lambda: _real_robot_online(session, lab.realm),
            30,
            f"{REAL_AGENT} online in {REAL_WORLD}",
        )

        # kill -9 one service: the supervisor says so and brings it back.
        victim = lab.children()[-1]
        victim_cmd = victim.cmdline()
        subcommand = victim_cmd[victim_cmd.index("services.cli") + 1]
        victim.kill()
        lab.wait_line("stopped by SIGKILL (killed)", timeout=20)
        lab.wait_line("restarting", timeout=20)
        replacement = wait_for(lambda: _alive_child(lab, subcommand), 30, "a new process")
        assert replacement.pid != victim.pid
        for key in expected_tokens(lab):
            assert watch.wait(key, 30), f"{key} did not come back"
    finally:
        watch.close()
        close_session(session)
    pids = [p.pid for p in lab.children()]
    assert pids
    code = lab.stop()  # Ctrl-C
    assert code == 0, "\n".join(lab.lines)
    assert "Lab stopped." in lab.lines
    left = [
        pid
        for pid in pids
        if psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    ]
    assert not left, f"children left running after Ctrl-C: {left}"


def _real_robot_online(session: zenoh.Session, realm: str) -> bool:
    for reply in session.get(keys.world_snapshot(realm, REAL_WORLD), timeout=5.0):
        if reply.ok is None:
            return False
        snap = decode(reply.ok.payload, WorldSnapshot)
        return any(a.id == REAL_AGENT and a.online for a in snap.agents)
    return False


def _alive_child(lab: UpLab, subcommand: str) -> psutil.Process | None:
    try:
        return lab.child(subcommand)
    except AssertionError:
        return None
