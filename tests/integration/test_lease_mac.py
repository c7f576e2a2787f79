"""MAC leases with real processes: an engine with an identity, a context, remote controllers."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from common import keys
from common.client.agent_client import DriveResult
from common.controller import Controller, Khepera
from common.messages import (
    AgentCommand,
    AuthEnvelope,
    Lease,
    MacCommand,
    MessageError,
    WorldSnapshot,
    decode,
)
from common.world.leasemac import mac_command, new_lease_key
from tests.conftest import Procs, Router, wait_for
from tests.integration.controllers.forward import Forward
from tests.kit.agentkit import (
    WORLD,
    Poses,
    agent_user,
    start_agent_context,
    start_engine,
)
from tests.kit.lab import ProcessLab, make_lab, module_lab

# One worker starts the module's lab once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]


class Still(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(0, 0)


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    """The lab of the tests that only read it or drive k0 to the end of their requests
    (the world-restart test starts its own)."""
    with module_lab(module_router, tmp_path_factory.mktemp("lab")) as lab:
        lab.start_registry()
        start_engine(lab, identity=True)
        start_agent_context(lab, slot=5.0)
        yield lab


class Wire:
    """What goes over k0's command and lease keys (a passive observer, as anyone may be)."""

    def __init__(self, z: zenoh.Session, realm: str) -> None:
        self.mac = 0
        self.signed = 0
        self.lease: Lease | None = None
        self._lock = threading.Lock()

        def on_cmd(sample: zenoh.Sample) -> None:
            try:
                message = decode(sample.payload, (MacCommand, AuthEnvelope))
            except MessageError:
                return
            with self._lock:
                if isinstance(message, MacCommand):
                    self.mac += 1
                else:
                    self.signed += 1

        def on_lease(sample: zenoh.Sample) -> None:
            try:
                lease = decode(decode(sample.payload, AuthEnvelope).body, Lease)
            except MessageError:
                return
            with self._lock:
                self.lease = lease

        self.subs = [
            z.declare_subscriber(keys.agent_cmd(realm, WORLD, "k0"), on_cmd),
            z.declare_subscriber(keys.agent_lease(realm, WORLD, "k0"), on_lease),
        ]


def test_world_identity_is_advertised(lab: ProcessLab) -> None:
    with lab.zsession() as z:
        replies = list(z.get(keys.world_snapshot(lab.router.realm, WORLD), timeout=10.0))
        snaps = [decode(r.ok.payload, WorldSnapshot) for r in replies if r.ok is not None]
        assert snaps and snaps[0].identity is not None


def test_controller_under_a_mac_lease_drives_and_a_non_holder_does_not(lab: ProcessLab) -> None:
    realm = lab.router.realm
    with lab.zsession() as z, agent_user(lab, "alice") as alice, agent_user(lab, "bob") as bob:
        poses = Poses(z, realm)
        wire = Wire(z, realm)
        done: list[DriveResult] = []
        t = threading.Thread(target=lambda: done.append(alice.drive("k0", Forward())))
        t.start()
        # The lease carries the key sealed to alice and to the engine; her link MACs.
        wait_for(lambda: wire.lease is not None and wire.lease.holder_key, 10, "a MAC lease")
        wait_for(lambda: wire.mac > 10, 10, "MAC commands from alice's link")
        signed = wire.signed
        start = poses.xy("k0")
        wait_for(
            lambda: float(np.linalg.norm(poses.xy("k0") - start)) > 10,
            5,
            "k0 driven by MAC commands",
        )
        assert wire.signed == signed, "once the MAC lease is in, no command is signed"
        t.join(15)
        assert done and done[0].status == "finished", done

        # Now alice holds k0 with a controller that keeps it still; bob knows the
        # lease id (anyone can read a lease) but not its key.
        done.clear()
        # Read before the request goes out: on a busy machine the second lease can
        # arrive before this thread runs again.
        first = wire.lease.lease_id if wire.lease is not None else None
        t = threading.Thread(target=lambda: done.append(alice.drive("k0", Still())))
        t.start()
        wait_for(
            lambda: (
                wire.lease is not None and wire.lease.lease_id != first and wire.lease.holder_key
            ),
            10,
            "alice's second lease",
        )
        wait_for(lambda: alice.position_of_user("alice", "k0") == 0, 10, "alice's slot")
        lease = wire.lease
        assert lease is not None
        key = keys.agent_cmd(realm, WORLD, "k0")
        guess = new_lease_key()
        time.sleep(0.3)  # let the still controller stop the robot (measurement start)
        start = poses.xy("k0")
        for seq in range(1, 21):
            command = AgentCommand(agent="k0", speeds=(40, 40))
            bob.client.z.put(
                key, mac_command(guess, key, lease.lease_id, 10**6 + seq, command, time.time())
            )
            time.sleep(0.02)  # pacing the flood, not waiting for a condition
        assert float(np.linalg.norm(poses.xy("k0") - start)) < 3
        t.join(15)
        assert done and done[0].status == "finished", done
        for sub in wire.subs:
            sub.undeclare()


class ForwardThenStill(Controller):
    """Drives forward for its first second, then holds the robot still."""

    period = 0.05

    def initialize(self, robot: Khepera) -> None:
        self.started = time.monotonic()

    def do_work(self, robot: Khepera) -> None:
        moving = time.monotonic() - self.started < 1.0
        robot.set_speeds(*((12, 12) if moving else (0, 0)))


def test_commands_sealed_before_a_world_restart_are_refused_after_it(
    router: Router, procs: Procs, tmp_path: Path
) -> None:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    engine = start_engine(lab, identity=True)
    start_agent_context(lab, slot=30.0)
    realm = lab.router.realm
    key = keys.agent_cmd(realm, WORLD, "k0")
    captured: list[bytes] = []
    with lab.zsession() as z, agent_user(lab, "alice") as alice:
        poses = Poses(z, realm)
        sub = z.declare_subscriber(key, lambda s: captured.append(bytes(s.payload.to_bytes())))
        stop = threading.Event()
        done: list[DriveResult] = []
        t = threading.Thread(
            target=lambda: done.append(alice.drive("k0", ForwardThenStill(), stop=stop))
        )
        t.start()
        wait_for(lambda: len(captured) > 10, 10, "alice's forward commands on the wire")
        forward = list(captured[:10])  # sealed while the lease was live, the robot moving
        engine.kill9()
        start_engine(lab, identity=True)  # the same world, restarted: a new epoch
        wait_for(lambda: poses.xy("k0") is not None, 10, "frames from the restarted world")
        # alice's lease is republished and resealed to the restarted world; her
        # controller is in its still phase by now, so nothing legitimate moves k0.
        time.sleep(2.5)  # the context's identity refresh (≤ 5 s) and the still phase settle
        start = poses.xy("k0").copy()
        for payload in forward * 3:  # replayed, 4 s after the restart as in the issue
            z.put(key, payload)
            time.sleep(0.02)  # pacing the replay, not waiting for a condition
        time.sleep(0.5)  # time for a replayed command to have moved the robot
        moved = float(np.linalg.norm(poses.xy("k0") - start))
        stop.set()
        t.join(15)
        sub.undeclare()
    assert moved < 1.0, f"replayed commands moved k0 {moved:.1f} mm after the world restarted"
