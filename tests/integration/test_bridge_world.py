"""``wart bridge`` as a real process on a real router, driving an emulated Khepera on a real pty.

The emulated robot runs in this test process (so the test can see where its
Sim2D body really is and pull its cable); the bridge opens its pty with
pyserial like a USB serial port. Waits are on conditions, never fixed sleeps;
thresholds leave room for a loaded 2-core machine.
"""

from __future__ import annotations

import json
import math
import os
import select
import threading
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from common import keys
from common.auth import RegistryIdentity, Session, issue_session
from common.keys import AliveKind
from common.messages import (
    AgentCommand,
    ErrorReply,
    Lease,
    SensorSample,
    WorldFrame,
    WorldSnapshot,
    decode,
)
from services.bridge import protocol as P
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.link import SerialKheperaLink
from services.bridge.simbody import SimBody
from services.lab.supervisor import AliveWatch
from tests.conftest import REPO, Proc, Procs, Router, wait_for
from tests.kit.leases import holder_lease
from tests.kit.waits import Latest

# One worker starts the module's router once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]
WORLD = "real1"
AGENT = "k1"


@pytest.fixture
def identity() -> RegistryIdentity:
    return RegistryIdentity.generate()


@pytest.fixture
def body() -> Iterator[SimBody]:
    with SimBody.from_map(REPO / "maps" / "empty.json", seed=2) as sim:
        yield sim


@pytest.fixture
def emulator(body: SimBody, tmp_path: Path) -> Iterator[KheperaEmulator]:
    emu = KheperaEmulator(body, EmulatorOptions(link_path=str(tmp_path / "khepera0")))
    with emu:
        yield emu


BridgeFactory = Callable[..., Proc]


@pytest.fixture
def start_bridge(
    router: Router, procs: Procs, identity: RegistryIdentity, alive_watch: AliveWatch
) -> BridgeFactory:
    def start(*extra: str) -> Proc:
        net = router.options(registry_key=identity.verify_key.hex()).as_args()
        proc = procs.start("bridge", ["bridge", "--world", WORLD, *extra, *net])
        key = keys.alive(router.realm, AliveKind.WORLD, WORLD)
        assert alive_watch.wait(key, 30.0, lambda: proc.popen.poll() is not None), proc.output()
        return proc

    return start


CentredRobot = Callable[[int], tuple[Latest, Session, Session]]


@pytest.fixture
def centred_robot(
    router: Router,
    zsession: zenoh.Session,
    start_bridge: BridgeFactory,
    emulator: KheperaEmulator,
    identity: RegistryIdentity,
) -> CentredRobot:
    """The bridge driving the robot from the arena's centre with a watchdog of so many ms,
    once its first sample is in: its samples, the agent context's session (to lease) and
    alice's (to drive)."""
    realm = router.realm

    def start(watchdog_ms: int) -> tuple[Latest, Session, Session]:
        port = f"{emulator.port}={AGENT}@500,500,0"
        start_bridge("--port", port, "--watchdog-ms", str(watchdog_ms))
        samples = Latest(zsession, keys.agent_sensors(realm, WORLD, AGENT), SensorSample)
        wait_for(lambda: samples.count > 0, 20, "a sensor sample")
        context = issue_session(identity, realm, "ctx", ["lease"])
        alice = issue_session(identity, realm, "alice", ["control"])
        return samples, context, alice

    return start


def snapshot(session: zenoh.Session, realm: str) -> WorldSnapshot:
    for reply in session.get(keys.world_snapshot(realm, WORLD), timeout=10.0):
        assert reply.ok is not None, reply.err
        snap = decode(reply.ok.payload, WorldSnapshot)
        assert isinstance(snap, WorldSnapshot)
        return snap
    raise AssertionError("no snapshot reply")


def online(session: zenoh.Session, realm: str, agent: str = AGENT) -> bool | None:
    agents = {a.id: a for a in snapshot(session, realm).agents}
    return agents[agent].online if agent in agents else None


def lease(holder: Session, *, start: float, end: float, lid: str = "L1") -> Lease:
    return holder_lease(holder, lease_id=lid, world_name=WORLD, agent=AGENT, start=start, end=end)


def moved(body: SimBody, since: tuple[float, float, float]) -> float:
    x, y, _ = body.pose()
    return math.hypot(x - since[0], y - since[1])


def test_samples_frames_and_snapshot_carry_the_robot(
    router: Router,
    zsession: zenoh.Session,
    start_bridge: BridgeFactory,
    emulator: KheperaEmulator,
    body: SimBody,
) -> None:
    realm = router.realm
    # Face the left wall from 12 mm: the front IR sensors read high.
    body.place(12 + 27.5, 500, math.pi)
    start_bridge("--port", f"{emulator.port}={AGENT}@39.5,500,180", "--arena-mm", "1000", "1000")
    samples = Latest(zsession, keys.agent_sensors(realm, WORLD, AGENT), SensorSample)
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: samples.count > 3 and frames.count > 3, 20, "samples and frames")
    sample = samples.get()
    assert isinstance(sample, SensorSample) and sample.world == WORLD and sample.agent == AGENT
    truth = body.proximity()
    assert min(sample.proximity[2], sample.proximity[3]) > 100, (sample.proximity, truth)
    assert abs(sample.proximity[2] - truth[2]) < 0.2 * truth[2] + 20, (sample.proximity, truth)
    assert max(sample.proximity[5:]) < 60, sample.proximity  # nothing behind or to the right
    assert all(300 < v <= 1023 for v in sample.ambient)  # no lamp in this map
    assert sample.speeds == (0, 0) and sample.leds == [0, 0]
    assert sample.gripper is not None and sample.gripper.fingers == "open"
    frame = frames.get()
    assert isinstance(frame, WorldFrame)
    x, y, heading = frame.poses.to_numpy()[0]
    assert abs(x - 39.5) < 1 and abs(y - 500) < 1 and abs(abs(heading) - math.pi) < 0.01
    snap = snapshot(zsession, realm)
    assert snap.rows == [AGENT] and (snap.width, snap.height) == (1000, 1000)
    assert snap.agents[0].type == "khepera" and snap.agents[0].online and snap.agents[0].gripper
    assert frame.layout == snap.layout
    # A real arena cannot be edited: a clear refusal, not a silent timeout.
    key = keys.world_edit(realm, WORLD)
    for reply in zsession.get(key, timeout=10.0):
        assert reply.ok is not None
        refused = decode(reply.ok.payload, ErrorReply)
        assert isinstance(refused, ErrorReply) and "real arena" in refused.message


def test_only_the_lease_holder_drives_and_the_watchdog_stops(
    router: Router,
    zsession: zenoh.Session,
    body: SimBody,
    identity: RegistryIdentity,
    centred_robot: CentredRobot,
) -> None:
    realm = router.realm
    samples, context, alice = centred_robot(300)
    mallory = issue_session(identity, realm, "mallory", ["control"])
    lease_key = keys.agent_lease(realm, WORLD, AGENT)
    cmd_key = keys.agent_cmd(realm, WORLD, AGENT)
    go = AgentCommand(agent=AGENT, speeds=(10, 10), leds=[True, False])

    def drive(who: Session, seconds: float) -> float:
        start = body.pose()
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            zsession.put(cmd_key, who.seal(cmd_key, go))
            time.sleep(0.05)  # a controller's period, not a wait for a condition
        return moved(body, start)

    assert drive(alice, 0.6) < 1.0  # no lease at all
    now = time.time()
    zsession.put(lease_key, context.seal(lease_key, lease(alice, start=now, end=now + 120)))
    fake = lease(mallory, start=now, end=now + 120, lid="L2")
    zsession.put(lease_key, mallory.seal(lease_key, fake))  # no 'lease' permission: ignored
    assert drive(mallory, 0.6) < 1.0
    assert drive(alice, 1.0) > 30.0  # 80 mm/s asked
    wait_for(
        lambda: isinstance(s := samples.get(), SensorSample) and s.leds == [1, 0],
        10,
        "LED 0 on in the samples",
    )
    # Watchdog: she stops sending; the lease is still in force, yet the wheels stop.
    wait_for(lambda: body.speed() == (0, 0), 10, "the watchdog to stop the motors")
    still = body.pose()
    wait_for(lambda: samples.count > 0, 1)
    assert moved(body, still) < 2.0
    # Expired lease: refused.
    now = time.time()
    zsession.put(lease_key, context.seal(lease_key, lease(alice, start=now - 10, end=now - 1)))
    wait_for(lambda: drive(alice, 0.3) < 1.0, 10, "commands under an ended lease to be refused")


def test_lease_end_halts_the_robot(
    router: Router, zsession: zenoh.Session, body: SimBody, centred_robot: CentredRobot
) -> None:
    realm = router.realm
    # A long watchdog, so only the lease's end can be what stops the robot.
    _, context, alice = centred_robot(60000)
    lease_key, cmd_key = keys.agent_lease(realm, WORLD, AGENT), keys.agent_cmd(realm, WORLD, AGENT)
    now = time.time()
    zsession.put(lease_key, context.seal(lease_key, lease(alice, start=now, end=now + 120)))
    go = AgentCommand(agent=AGENT, speeds=(5, 5))

    def accepted() -> bool:
        zsession.put(cmd_key, alice.seal(cmd_key, go))
        return body.speed() == (5, 5)

    wait_for(accepted, 10, "the leased command to reach the robot")
    now = time.time()
    zsession.put(lease_key, context.seal(lease_key, lease(alice, start=now - 10, end=now - 0.5)))
    wait_for(lambda: body.speed() == (0, 0), 10, "the lease's end to halt the robot")


def test_unplugged_robot_goes_offline_and_comes_back(
    router: Router,
    zsession: zenoh.Session,
    start_bridge: BridgeFactory,
    emulator: KheperaEmulator,
) -> None:
    realm = router.realm
    proc = start_bridge("--port", f"{emulator.port}={AGENT}")
    samples = Latest(zsession, keys.agent_sensors(realm, WORLD, AGENT), SensorSample)
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: online(zsession, realm) is True, 20, "the robot online")
    layout = snapshot(zsession, realm).layout
    emulator.unplug()
    wait_for(lambda: online(zsession, realm) is False, 20, "the robot reported offline")
    offline = snapshot(zsession, realm)
    assert offline.layout > layout and offline.rows == [AGENT]
    wait_for(
        lambda: isinstance(f := frames.get(), WorldFrame) and f.layout == offline.layout,
        10,
        "frames to carry the new layout",
    )
    emulator.plug()
    wait_for(lambda: online(zsession, realm) is True, 20, "the robot back online")
    count = samples.count
    wait_for(lambda: samples.count > count + 2, 10, "samples after the replug")
    assert proc.popen.poll() is None  # the same bridge process throughout


def test_autodetect_finds_the_robot_among_other_ports(
    router: Router,
    zsession: zenoh.Session,
    start_bridge: BridgeFactory,
    body: SimBody,
    tmp_path: Path,
) -> None:
    realm = router.realm
    scan = tmp_path / "scan"
    scan.mkdir()
    # Ports that are not robots: a silent serial device and one that echoes what it gets.
    silent_master, silent_slave = os.openpty()
    tty.setraw(silent_slave)
    echo_master, echo_slave = os.openpty()
    tty.setraw(echo_slave)
    os.symlink(os.ttyname(silent_slave), scan / "ttySILENT")
    os.symlink(os.ttyname(echo_slave), scan / "ttyECHO")
    stop = threading.Event()

    def echo() -> None:
        while not stop.is_set():
            try:
                if select.select([echo_master], [], [], 0.05)[0]:
                    os.write(echo_master, os.read(echo_master, 1024))
            except OSError:
                return

    threading.Thread(target=echo, daemon=True).start()
    emu = KheperaEmulator(body, EmulatorOptions(link_path=str(scan / "ttyKHEPERA")))
    try:
        start_bridge(
            "--autodetect",
            "--no-system-ports",
            "--scan",
            str(scan / "tty*"),
            "--scan-interval",
            "1",
            "--baud",
            "38400",
        )
        assert snapshot(zsession, realm).agents == []
        emu.start()  # plugged in after the bridge started: a later scan finds it
        wait_for(lambda: online(zsession, realm, "ttyKHEPERA") is True, 30, "the robot found")
        assert snapshot(zsession, realm).rows == ["ttyKHEPERA"]
    finally:
        stop.set()
        emu.stop()
        for fd in (silent_master, silent_slave, echo_master, echo_slave):
            os.close(fd)


def test_bridge_refuses_bad_arguments(procs: Procs) -> None:
    cases = [
        (["bridge", "--world", "real1"], "--port"),
        (["bridge", "--world", "bad/name", "--port", "/dev/null"], "--world"),
        (["bridge", "--world", "r", "--port", "/dev/x=no/pe"], "agent id"),
        (["bridge", "--world", "r", "--port", "/dev/x=k1@1,2"], "X,Y,HEADING_DEG"),
        (["bridge", "--world", "r", "--port", "/a=k1", "--port", "/b=k1"], "used twice"),
        (["bridge", "--world", "r", "--port", "/a", "--scan", "x"], "--autodetect"),
        (["bridge", "--world", "r", "--port", "/a", "--baud", "1200"], "invalid choice"),
    ]
    for i, (args, expected) in enumerate(cases):
        proc = procs.start(f"bad{i}", args)
        assert proc.popen.wait(30) == 2, proc.output()
        assert expected in proc.output(), proc.output()


def test_sim_backed_emulator_process_sees_the_walls_of_its_map(
    procs: Procs, tmp_path: Path
) -> None:
    arena = {"width": 600, "height": 400}
    robots = [
        {"id": "near", "type": "khepera", "x": 600 - 27.5 - 8, "y": 100, "heading_deg": 0},
        {"id": "far", "type": "khepera", "x": 300, "y": 300, "heading_deg": 0},
    ]
    path = tmp_path / "walls.json"
    path.write_text(
        json.dumps({"format": "wart-map", "version": 1, "arena": arena, "agents": robots})
    )

    def front_ir(agent: str) -> tuple[int, ...]:
        link = tmp_path / f"khepera-{agent}"
        proc = procs.start(
            f"emu-{agent}",
            ["khepera-emulator", "--map", str(path), "--agent", agent, "--link", str(link)],
        )
        wait_for(lambda: link.exists() or proc.popen.poll() is not None, 30, "the pty link")
        assert proc.popen.poll() is None, proc.output()
        serial_link = SerialKheperaLink.open(str(link), 38400)
        try:
            return serial_link.request(P.read_proximity()).values
        finally:
            serial_link.close()
            proc.stop()

    near, far = front_ir("near"), front_ir("far")
    assert min(near[2], near[3]) > 150, near
    assert max(far) < 50, far
    bad = procs.start("emu-bad", ["khepera-emulator", "--map", str(path), "--agent", "k9"])
    assert bad.popen.wait(30) == 2 and "no agent 'k9'" in bad.output(), bad.output()
