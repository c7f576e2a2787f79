"""A real engine process on a real router: frames, sensors, snapshot, leases, watchdog, edits."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zenoh

from common import keys
from common.auth import RegistryIdentity, Session, issue_session
from common.controller import RobotCommand
from common.keys import AliveKind
from common.messages import (
    AddItem,
    AgentCommand,
    BundledCommand,
    CommandBundle,
    EditResult,
    ErrorReply,
    Lease,
    MapRequest,
    Message,
    MoveItem,
    SampleBundle,
    SensorSample,
    WorldEdit,
    WorldFrame,
    WorldLayout,
    WorldSnapshot,
    decode,
    encode,
)
from common.service import close_session, open_session
from common.sim2d import compiled
from common.sim2d.world import DRIVES, OBJECT_DRIVES
from common.world.remote_robot import WorldChannel, ZenohRobotLink
from services.lab.supervisor import AliveWatch
from tests.conftest import REPO, Procs, Router, wait_for
from tests.kit.leases import holder_lease
from tests.kit.waits import Latest
from viewers.web.live_world import WorldWatch

# One worker starts the module's router and shared engine once.
pytestmark = [pytest.mark.one_worker, pytest.mark.shared_router]
WORLD = "w1"


@pytest.fixture
def identity() -> RegistryIdentity:
    return RegistryIdentity.generate()


@dataclass
class Engine:
    """The module's engine (maps/foraging.json), shared by the tests that watch, lease or edit:
    each ends its leases (``end_leases``), so the others' "nothing leased" controls hold."""

    realm: str
    identity: RegistryIdentity
    maps_dir: Path


@pytest.fixture(scope="module")
def engine(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Engine]:
    tmp = tmp_path_factory.mktemp("engine")
    procs = Procs(tmp)
    identity = RegistryIdentity.generate()
    session = open_session(module_router.options(), wait=10.0)
    watch = AliveWatch(session, keys.alive_all(module_router.realm))
    try:
        yield Engine(
            module_router.realm,
            identity,
            start_engine(module_router, procs, identity, watch, tmp),
        )
    finally:
        watch.close()
        close_session(session)
        procs.stop_all()


def end_leases(
    session: zenoh.Session, engine: Engine, context: Session, leases: list[Lease]
) -> None:
    """Publish each lease again ending in the past (same id), and return once the engine
    has none in force: frames go on without a sample bundle between them.

    The engine bundles samples only while someone subscribes, so a bundle is awaited first
    (the engine has seen this subscriber); if none comes, the leases were not in force
    (a test that failed before granting them) and there is nothing to prove."""
    if not leases:
        return
    bundles = Latest(session, keys.world_samples(engine.realm, WORLD), SampleBundle)
    frames = Latest(session, keys.world_frame(engine.realm, WORLD), WorldFrame)
    in_force = time.monotonic() + 5.0
    while bundles.count == 0 and time.monotonic() < in_force:
        time.sleep(0.02)
    now = time.time()
    for lease in leases:
        key = keys.agent_lease(engine.realm, WORLD, lease.agent)
        ended = msgspec.structs.replace(lease, start=now - 10, end=now - 1)
        session.put(key, context.seal(key, ended))
    seen = [bundles.count, frames.count]

    def no_bundles() -> bool:
        if bundles.count != seen[0]:
            seen[:] = [bundles.count, frames.count]
            return False
        return frames.count - seen[1] >= 5

    wait_for(no_bundles, 10, "the engine to drop the ended leases")
    bundles.sub.undeclare()
    frames.sub.undeclare()


def start_engine(
    router: Router,
    procs: Procs,
    identity: RegistryIdentity,
    alive_watch: AliveWatch,
    tmp_path: Path,
    *extra: str,
    objects: bool = True,
) -> Path:
    """`wart engine` on a copy of maps/foraging.json (4 Khepera), its token seen.

    Without ``objects`` the copy has no balls or crate.
    """
    maps_dir = tmp_path / "maps"
    maps_dir.mkdir()
    shutil.copy(REPO / "maps" / "foraging.json", maps_dir / "foraging.json")
    if not objects:
        path = maps_dir / "foraging.json"
        document = json.loads(path.read_text())
        document["objects"] = []
        path.write_text(json.dumps(document))
    net = router.options(registry_key=identity.verify_key.hex()).as_args()
    proc = procs.start(
        "engine",
        [
            "engine",
            "--map",
            str(maps_dir / "foraging.json"),
            "--world",
            WORLD,
            "--seed",
            "3",
            "--watchdog-ms",
            "300",
            *extra,
            *net,
        ],
    )
    key = keys.alive(router.realm, AliveKind.WORLD, WORLD)
    # A drive the ahead-of-time module lacks (joints, velocity) has numba compile its kernels
    # as the engine starts, unless numba's cache has them (./dev test fills it beside the
    # first tests): at a CI run's start, more than 30 s. The engine says it, and is waited on.
    compiling = "loading numba's for what the ahead-of-time module lacks"
    up = alive_watch.wait(key, 30.0) or (
        compiling in proc.output() and alive_watch.wait(key, 150.0)
    )
    assert up, proc.output()
    return maps_dir


def ask(session: zenoh.Session, key: str, payload: bytes | None = None) -> Message:
    for reply in session.get(key, payload=payload, timeout=10.0):
        assert reply.ok is not None, reply.err
        return decode(reply.ok.payload, (WorldSnapshot, EditResult, ErrorReply))
    raise AssertionError(f"no reply on {key}")


def lease_for(
    realm: str, holder: Session, *, start: float, end: float, lid: str = "L1", agent: str = "k0"
) -> Lease:
    return holder_lease(holder, lease_id=lid, world_name=WORLD, agent=agent, start=start, end=end)


def x_of(frame: object, row: int = 0) -> float:
    assert isinstance(frame, WorldFrame)
    return float(frame.poses.to_numpy()[row, 0])


def test_bad_map_file_gives_a_clear_error(procs: Procs, tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"format": "wart-map", "version": 1,\n "arena": {"width": 500 "height": 1}}\n')
    typo = tmp_path / "typo.json"
    typo.write_text(
        json.dumps(
            {
                "format": "wart-map",
                "version": 1,
                "arena": {"width": 500, "height": 500},
                "objects": [
                    {"id": "b", "shape": "circle", "x": 10, "y": 10, "radius": 5, "colr": "#ffffff"}
                ],
            }
        )
    )
    # Both at once: each process spends its seconds importing before it reads its map.
    proc = procs.start("engine-bad", ["engine", "--map", str(bad)])
    typo_proc = procs.start("engine-typo", ["engine", "--map", str(typo)])
    assert proc.popen.wait(30) == 2
    assert "line 3" in proc.output() or "line 2" in proc.output(), proc.output()
    assert typo_proc.popen.wait(30) == 2
    assert "objects[0].colr" in typo_proc.output(), typo_proc.output()


# Every drive (`wart engine --drive`): the swarm options run the same service.
@pytest.mark.parametrize("drive", DRIVES)
def test_wander_moves_undriven_robots_and_leaves_driven_ones_to_their_controller(
    router: Router,
    procs: Procs,
    identity: RegistryIdentity,
    alive_watch: AliveWatch,
    zsession: zenoh.Session,
    tmp_path: Path,
    drive: str,
) -> None:
    start_engine(
        router,
        procs,
        identity,
        alive_watch,
        tmp_path,
        "--wander",
        "--drive",
        drive,
        objects=drive in OBJECT_DRIVES,
    )
    realm = router.realm
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: frames.count > 0, 10, "a frame")

    def poses() -> np.ndarray:
        frame = frames.get()
        assert isinstance(frame, WorldFrame)
        return frame.poses.to_numpy()[:4].astype(float)  # k0..k3 come first

    def moved(before: np.ndarray, after: np.ndarray) -> np.ndarray:
        return np.hypot(*(after[:, :2] - before[:, :2]).T) + 100 * abs(after[:, 2] - before[:, 2])

    # Nobody drives: every robot moves (or turns away from what it sees) on its own
    # (in 1.5 s on a quiet machine; a busy one's engine may tick behind the clock).
    before = poses()
    wait_for(
        lambda: bool((moved(before, poses()) > 10).all()),
        20,
        "every robot wandering 10 mm (or turning)",
    )

    # k0's lease holder commands it to stand still: it obeys its controller, not the rule,
    # while the others keep wandering.
    alice = issue_session(identity, realm, "alice", ["control"])
    context = issue_session(identity, realm, "ctx", ["lease"])
    lease_key, cmd_key = keys.agent_lease(realm, WORLD, "k0"), keys.agent_cmd(realm, WORLD, "k0")
    now = time.time()
    zsession.put(
        lease_key, context.seal(lease_key, lease_for(realm, alice, start=now, end=now + 60))
    )
    halt = AgentCommand(agent="k0", speeds=(0, 0))

    def k0_halted() -> bool:
        # The lease and the first commands have landed once k0 stands across a few frames.
        zsession.put(cmd_key, alice.seal(cmd_key, halt))
        first, seen = poses(), frames.count
        wait_for(lambda: frames.count >= seen + 3, 10, "three more frames")
        zsession.put(cmd_key, alice.seal(cmd_key, halt))
        return bool(moved(first, poses())[0] < 0.5)

    wait_for(k0_halted, 30, "k0 standing still for its lease holder")
    engine = next(p for p in procs.started if p.name == "engine")
    lapse = "watchdog: no command for k0"
    lapses = engine.output().count(lapse)
    before = poses()
    for _ in range(20):  # a controller's period, not a wait for a condition
        zsession.put(cmd_key, alice.seal(cmd_key, halt))
        time.sleep(0.05)
    held = moved(before, poses())
    # k0 holds while its commands come in time. On a busy machine this loop's 50 ms can
    # stretch past the 300 ms watchdog (seen at load 10: k0 moved 7.7): the engine then
    # stops k0 and hands it back to the rule, as designed, and says so in its log.
    if engine.output().count(lapse) == lapses:
        assert held[0] < 2.0, held
    assert (held[1:] > 5).all(), held

    # Her commands stop: after the watchdog, k0 wanders again.
    before = poses()
    wait_for(lambda: moved(before, poses())[0] > 10, 20, "k0 wandering again")


def test_a_big_world_publishes_a_robots_samples_once_it_is_watched_or_leased(
    router: Router,
    procs: Procs,
    zsession: zenoh.Session,
    identity: RegistryIdentity,
    alive_watch: AliveWatch,
    tmp_path: Path,
) -> None:
    # Four robots over --streams-up-front 2: the engine declares no sensor
    # publisher up front (at 10,000 robots that took 35 s), only for robots
    # someone watches (their agent/<a>/watch token) or that are leased.
    start_engine(router, procs, identity, alive_watch, tmp_path, "--streams-up-front", "2")
    realm = router.realm
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    plain = Latest(zsession, keys.agent_sensors(realm, WORLD, "k1"), SensorSample)
    watched = Latest(zsession, keys.agent_sensors(realm, WORLD, "k2"), SensorSample)
    leased = Latest(zsession, keys.agent_sensors(realm, WORLD, "k3"), SensorSample)
    wait_for(lambda: frames.count > 20, 15, "frames")
    assert watched.count == 0 and plain.count == 0, "no publisher was declared up front"

    # Tokens for robots the world does not have (stale, or a flood from a hostile
    # client) are dropped: the engine goes on serving.
    ghosts = [
        zsession.liveliness().declare_token(keys.agent_watch(realm, WORLD, f"ghost{i}"))
        for i in range(300)
    ]
    token = zsession.liveliness().declare_token(keys.agent_watch(realm, WORLD, "k2"))
    wait_for(lambda: watched.count > 5, 15, "k2's samples once watched")
    sample = watched.get()
    assert isinstance(sample, SensorSample) and sample.agent == "k2"

    context = issue_session(identity, realm, "ctx", ["lease"])
    alice = issue_session(identity, realm, "alice", ["control"])
    now = time.time()
    lease_key = keys.agent_lease(realm, WORLD, "k3")
    lease = lease_for(realm, alice, start=now, end=now + 60, agent="k3")
    zsession.put(lease_key, context.seal(lease_key, lease))
    wait_for(lambda: leased.count > 5, 15, "k3's samples once leased")

    # A robot watched once keeps its publisher: samples go on after the token
    # is gone (to whoever subscribes), and a link (ZenohRobotLink) watches too.
    token.undeclare()
    seen = watched.count
    wait_for(lambda: watched.count > seen + 5, 15, "k2's samples after the token")
    assert plain.count == 0, "k1 was neither watched nor leased"
    link = ZenohRobotLink(zsession, realm, WORLD, "k1", lambda: alice)
    try:
        wait_for(lambda: plain.count > 5, 15, "k1's samples once a link reads them")
    finally:
        link.close(stop=False)
    # The web viewer's robot panel watches the robot it shows.
    panel = WorldWatch(zsession, realm, WORLD)
    try:
        panel.ready()
        wait_for(lambda: panel.sensors("k0") is not None, 15, "k0's readings in the viewer")
    finally:
        panel.close()
    engine_log = procs.started[-1].output()
    assert "4 robots, more than --streams-up-front 2" in engine_log, engine_log
    assert "k2's sensor samples published from now on (someone watches it)" in engine_log
    assert "k3's sensor samples published from now on (leased)" in engine_log
    assert "ghost" not in engine_log
    # It says which kernels it runs: the module compiled ahead of time where built
    # (./dev test builds it), as this process chose (the same environment and checkout).
    said = {"aot": "engine: kernels: ahead of time", "jit": "engine: kernels: numba's"}
    assert said[compiled.PATH] in engine_log, engine_log
    for ghost in ghosts:
        ghost.undeclare()


# The shared engine's tests come last: it runs from the first of them to the module's end,
# and would otherwise load the machine while the tests above start engines of their own.
def test_frames_sensors_and_snapshot(zsession: zenoh.Session, engine: Engine) -> None:
    realm = engine.realm
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    sensors = Latest(zsession, keys.agent_sensors(realm, WORLD, "k0"), SensorSample)
    wait_for(lambda: frames.count > 5 and sensors.count > 5, 15, "frames and sensor samples")
    snap = ask(zsession, keys.world_snapshot(realm, WORLD))
    assert isinstance(snap, WorldSnapshot)
    assert snap.rows[:4] == ["k0", "k1", "k2", "k3"] and "ball0" in snap.rows
    assert {i.category for i in snap.items} == {"obstacle", "object", "zone"}
    assert snap.agents[0].type == "khepera" and snap.agents[0].gripper
    frame = frames.get()
    assert isinstance(frame, WorldFrame) and frame.layout == snap.layout
    assert frame.poses.to_numpy().shape == (len(snap.rows), 3)
    sample = sensors.get()
    assert isinstance(sample, SensorSample) and len(sample.proximity) == 8
    assert sample.gripper is not None and sample.gripper.arm == 255
    assert sample.ambient[0] < 500  # the nest lamp is near


def test_only_the_lease_holder_drives_and_the_watchdog_stops(
    zsession: zenoh.Session, engine: Engine
) -> None:
    realm, identity = engine.realm, engine.identity
    context = issue_session(identity, realm, "ctx", ["lease"])
    alice = issue_session(identity, realm, "alice", ["control"])
    mallory = issue_session(identity, realm, "mallory", ["control"])
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: frames.count > 0, 10, "a frame")
    lease_key = keys.agent_lease(realm, WORLD, "k0")
    cmd_key = keys.agent_cmd(realm, WORLD, "k0")
    go = AgentCommand(agent="k0", speeds=(10, 10))

    def drive(who: Session, seconds: float, far: float | None = None) -> float:
        """Send ``who``'s command at a controller's period for ``seconds`` (or, with ``far``,
        until the robot has moved that far): how far it moved meanwhile."""
        start_x = x_of(frames.get())
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            zsession.put(cmd_key, who.seal(cmd_key, go))
            time.sleep(0.05)  # a controller's period, not a wait for a condition
            if far is not None and x_of(frames.get()) - start_x > far:
                break
        return x_of(frames.get()) - start_x

    def stands_still() -> bool:
        """Two frames 0.3 simulated s apart put the robot at the same place."""
        first = frames.get()
        assert isinstance(first, WorldFrame)
        later = wait_for(
            lambda: (f := frames.get()) is not None and f.sim_time >= first.sim_time + 0.3 and f,
            10,
            "a frame 0.3 simulated s later",
        )
        return abs(x_of(later) - x_of(first)) < 1.0

    # No lease at all: nothing moves.
    assert abs(drive(alice, 0.6)) < 1.0
    now = time.time()
    lease = lease_for(realm, alice, start=now, end=now + 60)
    zsession.put(lease_key, context.seal(lease_key, lease))
    try:
        # A lease published by someone without the 'lease' permission is ignored.
        fake = lease_for(realm, mallory, start=now, end=now + 60, lid="L2")
        zsession.put(lease_key, mallory.seal(lease_key, fake))
        # Alice's last command of the drive before her lease may be applied once it holds
        # (late on a busy machine: 24 mm, a watchdog's worth): the robot still first.
        wait_for(stands_still, 10, "the robot still before mallory drives")
        # Mallory does not hold the lease.
        assert abs(drive(mallory, 0.6)) < 1.0
        # Alice does (80 mm/s; a busy machine's engine may run slower than the clock).
        moved = drive(alice, 20.0, far=40.0)
        assert moved > 40.0, moved
        # Watchdog: she stops sending; within 300 ms (plus delivery) the robot stops.
        wait_for(stands_still, 10, "the robot stopped by the watchdog")
    finally:
        # The lease ends early (same id, new end): once the engine has dropped it (no more
        # sample bundles), the next tests find none in force.
        end_leases(zsession, engine, context, [lease])
    # Her commands are refused now.
    assert abs(drive(alice, 0.6)) < 1.0


def test_edits_need_edit_map_and_are_validated(zsession: zenoh.Session, engine: Engine) -> None:
    realm, identity = engine.realm, engine.identity
    editor = issue_session(identity, realm, "teacher", ["edit_map"])
    student = issue_session(identity, realm, "student", ["control"])
    edit_key = keys.world_edit(realm, WORLD)
    map_key = keys.world_map(realm, WORLD)
    move = WorldEdit(op=MoveItem(id="rock1", x=800.0, y=900.0))
    refused = ask(zsession, edit_key, student.seal(edit_key, move))
    assert isinstance(refused, ErrorReply) and refused.code == "forbidden"
    unsigned = ask(zsession, edit_key, b"junk")
    assert isinstance(unsigned, ErrorReply) and unsigned.code == "unauthenticated"
    before = ask(zsession, keys.world_snapshot(realm, WORLD))
    assert isinstance(before, WorldSnapshot)
    done = ask(zsession, edit_key, editor.seal(edit_key, move))
    assert isinstance(done, EditResult) and done.layout > before.layout
    outside = WorldEdit(op=MoveItem(id="rock1", x=5000.0, y=900.0))
    bad = ask(zsession, edit_key, editor.seal(edit_key, outside))
    assert isinstance(bad, ErrorReply) and bad.code == "conflict" and "arena" in bad.message
    onto_wall = WorldEdit(op=AddItem(section="agents", entry={"id": "k9", "x": 1250, "y": 300}))
    bad = ask(zsession, edit_key, editor.seal(edit_key, onto_wall))
    assert isinstance(bad, ErrorReply) and "overlap an obstacle" in bad.message
    # Who reads no frames (an agent context between slots) hears of new rows all the same.
    news: list[WorldLayout] = []
    told = zsession.declare_subscriber(
        keys.world_layout(realm, WORLD), lambda s: news.append(decode(s.payload, WorldLayout))
    )
    add = WorldEdit(op=AddItem(section="agents", entry={"id": "k9", "x": 1400, "y": 150}))
    assert isinstance(ask(zsession, edit_key, editor.seal(edit_key, add)), EditResult)
    after = ask(zsession, keys.world_snapshot(realm, WORLD))
    assert isinstance(after, WorldSnapshot) and "k9" in after.rows
    wait_for(lambda: any(n.layout == after.layout for n in news), 10, "the new layout said")
    assert {n.world for n in news} == {WORLD}
    told.undeclare()
    rock = next(i for i in after.items if i.id == "rock1")
    assert (rock.x, rock.y) == (800.0, 900.0)
    # Save under a plain name; paths are refused; then load it back.
    saved = ask(zsession, map_key, editor.seal(map_key, MapRequest(action="save", name="edited")))
    assert isinstance(saved, EditResult), saved
    data = json.loads((engine.maps_dir / "edited.json").read_text())
    assert any(a["id"] == "k9" for a in data["agents"])
    evil = b'{"action": "save", "name": "../x"}'
    assert isinstance(ask(zsession, map_key, evil), ErrorReply)
    loaded = ask(zsession, map_key, editor.seal(map_key, MapRequest(action="load", name="edited")))
    assert isinstance(loaded, EditResult), loaded
    listed = ask(zsession, map_key, editor.seal(map_key, MapRequest(action="list")))
    assert isinstance(listed, EditResult) and "edited" in listed.maps


def test_sample_bundles_hold_the_leased_agents_and_bundled_commands_are_checked_one_by_one(
    zsession: zenoh.Session, engine: Engine
) -> None:
    """world/<w>/samples and world/<w>/cmds, the runner's path, obey the same leases."""
    realm, identity = engine.realm, engine.identity
    context = issue_session(identity, realm, "ctx", ["lease"])
    alice = issue_session(identity, realm, "alice", ["control"])
    bob = issue_session(identity, realm, "bob", ["control"])
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    bundles = Latest(zsession, keys.world_samples(realm, WORLD), SampleBundle)
    wait_for(lambda: frames.count > 5, 10, "frames")
    assert bundles.count == 0, "no lease in force: nothing to bundle"

    now = time.time()
    leases = [
        lease_for(realm, holder, start=now, end=now + 60, lid=f"L{agent}", agent=agent)
        for agent, holder in (("k2", alice), ("k1", bob))
    ]
    try:
        for lease in leases:
            key = keys.agent_lease(realm, WORLD, lease.agent)
            zsession.put(key, context.seal(key, lease))
        wait_for(lambda: bundles.count > 3, 10, "sample bundles")
        got = bundles.get()
        assert isinstance(got, SampleBundle) and got.agents == ["k1", "k2"]
        samples = [decode(bytes(raw), SensorSample) for raw in got.samples]
        assert [s.agent for s in samples] == ["k1", "k2"] and samples[0].tick == got.tick

        def command(who: Session, agent: str) -> BundledCommand:
            key = keys.agent_cmd(realm, WORLD, agent)
            return BundledCommand(agent, who.seal(key, AgentCommand(agent=agent, speeds=(10, 10))))

        def xs() -> np.ndarray:
            frame = frames.get()
            assert isinstance(frame, WorldFrame)
            return frame.poses.to_numpy()[:3, 0].astype(float)

        cmds_key = keys.world_commands(realm, WORLD)
        zsession.put(cmds_key, b"\x92garbage")  # malformed: dropped, the engine keeps serving
        start = xs()
        moved = xs() - start
        # Until k2 has driven 40 mm (half a second at these speeds on a quiet machine; a
        # busy one ticks and sends frames late), every bundle asking for all three.
        deadline = time.monotonic() + 20.0
        while moved[2] <= 40.0 and time.monotonic() < deadline:
            bundle = CommandBundle(
                commands=[
                    command(alice, "k0"),  # no lease on k0: refused
                    command(alice, "k1"),  # k1 is bob's: refused, without spoiling the rest
                    command(alice, "k2"),  # alice holds k2: obeyed
                ]
            )
            zsession.put(cmds_key, encode(bundle))
            time.sleep(0.05)  # a controller's period
            moved = xs() - start
        assert moved[2] > 40.0, moved
        assert abs(moved[0]) < 1.0 and abs(moved[1]) < 1.0, moved
    finally:
        end_leases(zsession, engine, context, leases)


def test_a_swarm_answers_its_leased_robots_from_one_tick_listener(
    zsession: zenoh.Session, engine: Engine
) -> None:
    """WorldChannel.on_tick on a real router: called with each tick's leased agents, drives them."""
    realm, identity = engine.realm, engine.identity
    context = issue_session(identity, realm, "ctx", ["lease"])
    alice = issue_session(identity, realm, "alice", ["control"])
    frames = Latest(zsession, keys.world_frame(realm, WORLD), WorldFrame)
    wait_for(lambda: frames.count > 5, 10, "frames")
    channel = WorldChannel(zsession, realm, WORLD)
    links = {
        # No keep-alives: every put counted below is the listener's.
        agent: ZenohRobotLink(
            zsession, realm, WORLD, agent, lambda: alice, channel=channel, keepalive=3600.0
        )
        for agent in ("k0", "k1", "k2")
    }
    calls: list[tuple[int, list[str]]] = []
    leases: list[Lease] = []

    def swarm(tick: int, agents: list[str]) -> None:
        calls.append((tick, agents))
        for agent in agents:
            links[agent].send(RobotCommand(speeds=(10, 10)))

    try:
        channel.on_tick(swarm)
        time.sleep(0.5)
        assert calls == [], "no lease in force: no bundle, no call"

        def xs() -> np.ndarray:
            frame = frames.get()
            assert isinstance(frame, WorldFrame)
            return frame.poses.to_numpy()[:3, 0].astype(float)

        start = xs()
        now = time.time()
        for agent in ("k1", "k2"):  # alice holds these two; k0 has no lease
            lease = lease_for(realm, alice, start=now, end=now + 60, lid=f"S{agent}", agent=agent)
            leases.append(lease)
            key = keys.agent_lease(realm, WORLD, agent)
            zsession.put(key, context.seal(key, lease))
        wait_for(lambda: len(calls) > 25, 10, "tick listener calls")
        # 40 mm each (half a second at these speeds; later on a busy machine).
        wait_for(lambda: min((xs() - start)[1:3]) > 40.0, 20, "k1 and k2 40 mm on")
        moved = xs() - start
        assert abs(moved[0]) < 1.0, moved  # not leased: neither called for nor moved
        ticks = [tick for tick, _ in calls]
        assert ticks == sorted(set(ticks)), "one call per bundle, in tick order"
        # The two leases arrive one after the other: a tick may fall between them.
        assert all(set(agents) <= {"k1", "k2"} for _, agents in calls), calls[:3]
        assert calls[-1][1] == ["k1", "k2"], calls[-3:]
        assert channel.puts <= channel.bundles, "one command message per tick at most"
    finally:
        for link in links.values():
            link.close(stop=False)
        channel.close()
        end_leases(zsession, engine, context, leases)
