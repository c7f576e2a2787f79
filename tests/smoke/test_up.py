"""``wart up`` brings a lab up, restarts a killed child, and leaves nothing behind on Ctrl-C."""

from __future__ import annotations

import argparse
from pathlib import Path

import psutil
import pytest
import zenoh

from common import keys
from common.messages import WorldSnapshot, decode
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.commands.up import REAL_AGENT, REAL_WORLD, lab_plan, router_spec, settings_from_args
from services.lab.supervisor import AliveWatch
from tests.conftest import wait_for
from tests.kit.lab import UpLab

pytestmark = pytest.mark.smoke


def expected_tokens(lab: UpLab) -> list[str]:
    args = argparse.Namespace(state_dir=lab.state_dir, port=lab.port, http_port=lab.http_port)
    settings = settings_from_args(args, NetworkOptions(realm=lab.realm))
    specs = [router_spec(settings), *lab_plan(settings)]
    return [spec.alive_key for spec in specs if spec.alive_key]


def test_lab_comes_up_restarts_a_killed_child_and_stops_cleanly(tmp_path: Path, realm: str) -> None:
    lab = UpLab(realm=realm, state_dir=tmp_path / "state").start()
    try:
        lab.wait_line("The lab is running", timeout=120)
        session = open_session(NetworkOptions(realm=realm, connect=(lab.endpoint,)), wait=10)
        watch = AliveWatch(session, keys.alive_all(realm))
        try:
            for key in expected_tokens(lab):
                assert watch.wait(key, 20), f"{key} never appeared:\n" + "\n".join(lab.lines)
            # The real-robot path without hardware: the bridge has the emulated Khepera online.
            wait_for(
                lambda: _real_robot_online(session, realm),
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
    finally:
        code = lab.stop()
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
