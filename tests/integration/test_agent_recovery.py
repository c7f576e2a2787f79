"""An agent context killed with -9 comes back with its queues, settings and running slot."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from common.client.agent_client import DriveResult
from common.controller import Controller, Khepera
from tests.conftest import Procs, Router, wait_for
from tests.kit.agentkit import Poses, agent_users, start_agent_context, start_engine
from tests.kit.lab import make_lab


class Forward(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(10, 10)


def test_queues_settings_and_the_running_slot_survive_a_kill(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab, identity=True)
    started = time.monotonic()
    context = start_agent_context(lab, slot=30.0)
    up_s = time.monotonic() - started
    with (
        lab.zsession() as z,
        agent_users(lab, "alice", "bob", "ida") as (alice, bob, ida),
    ):
        poses = Poses(z, lab.router.realm)
        # alice's slot must outlast a kill and a restart (Python, numpy and Zenoh
        # loading: several seconds on a busy machine) and the checks after it; its
        # end is then waited for. Sized from how long the context took to come up
        # just now (the restart costs about as much), rather than a fixed 30 s:
        # 12 s on a quiet machine, up to 30 s on a very busy one.
        slot = min(30.0, max(12.0, 8.0 + 5.0 * up_s))
        ida.settings(slot_seconds=slot)  # alice's slot, the next one, is this long
        done: list[DriveResult] = []
        t = threading.Thread(target=lambda: done.append(alice.drive("k0", Forward())))
        t.start()
        wait_for(lambda: alice.position_of_user("alice", "k0") == 0, 10, "alice's slot")
        waiting = bob.queue("k0", "remote")
        assert waiting.position == 1
        ida.settings(slot_seconds=25.0)  # the owner's live setting
        killed_at = time.monotonic()
        context.kill9()
        restarted = start_agent_context(lab, slot=30.0)
        back = time.monotonic() - killed_at
        # the clients rejoin by themselves and see the restored queue
        wait_for(lambda: bob.position(waiting.request_id) is not None, 10, "bob's request back")
        whole = time.monotonic() - killed_at
        print(
            f"agent context up in {up_s:.2f} s, slot {slot:.1f} s; back {back:.2f} s, "
            f"clients whole {whole:.2f} s after kill -9"
        )
        assert bob.position(waiting.request_id)[0] == 1
        assert alice.position_of_user("alice", "k0") == 0
        state = bob.state()
        assert state.slot_seconds == 25.0
        # alice keeps driving through the restart, and her slot ends as it was going to
        start = poses.xy("k0").copy()
        wait_for(lambda: np.linalg.norm(poses.xy("k0") - start) > 5, 5, "k0 still driven")
        t.join(60)
        assert done and done[0].status == "finished", done
        bob.cancel_quietly(waiting.request_id)
    assert "restored 1 waiting and 1 running requests" in restarted.output()
