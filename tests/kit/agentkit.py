"""Agent labs for integration tests: what they watch and drive (poses, motion, a user).

The processes (engine, runner, agent context) are started by tests/kit/lab.py, the one
lab starter; the start_* functions here are its shorthands for the agent tests.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np
import zenoh

from common import keys
from common.client.agent_client import AgentClient
from common.client.lab_client import LabClient
from common.keys import AliveKind
from common.messages import WorldFrame, WorldSnapshot, decode
from common.service import close_session, open_session
from services.bridge.emulator import EmulatorOptions, KheperaEmulator
from services.bridge.simbody import SimBody
from tests.kit.lab import PASSWORD, ProcessLab
from tests.kit.procs import Proc
from tests.kit.waits import wait_for

WORLD = "w1"
CTX = "arena"


def service_account(lab: ProcessLab, account: str) -> Path:
    """A service account and its identity key (tests/kit/lab.py makes them)."""
    return lab.account(account)


def start_engine(
    lab: ProcessLab,
    map_name: str = "foraging",
    *,
    identity: bool = False,
    world: str = WORLD,
    env: dict[str, str] | None = None,
) -> Proc:
    """The engine of ``world``; with ``identity`` it logs in as a service account (MAC leases)."""
    return lab.start_engine(map_name, world=world, identity=identity, env=env)


def together(*starts: Callable[[], Proc]) -> list[Proc]:
    """Run start functions at once (each starts a process and waits for its token).

    For processes that do not need each other (an engine and a runner): their
    start-up, mostly imports and loading compiled kernels, overlaps. A start
    that fails raises here, after the others have finished.
    """
    with ThreadPoolExecutor(len(starts), thread_name_prefix="start") as pool:
        futures = [pool.submit(start) for start in starts]
    return [future.result() for future in futures]


def start_runner(lab: ProcessLab, name: str = "runner") -> Proc:
    return lab.start_runner(name)


def start_agent_lab(
    lab: ProcessLab,
    *context_args: str,
    map_name: str = "foraging",
    identity: bool = False,
    slot: float = 2.5,
) -> tuple[Proc, Proc, Proc]:
    """The services an agent test drives: the registry, then the engine and the runner
    (together), then the agent context; returns (engine, runner, agent context)."""
    lab.start_registry()
    engine, runner = together(
        lambda: start_engine(lab, map_name, identity=identity), lambda: start_runner(lab)
    )
    context = start_agent_context(lab, *context_args, slot=slot)
    return engine, runner, context


@contextmanager
def bridged_robot(
    lab: ProcessLab, body: SimBody, link: Path, at: str, *extra: str, world: str = WORLD
) -> Iterator[Proc]:
    """A real arena of one robot, k1: an emulated Khepera moving ``body``, on the pty
    ``link``, behind ``wart bridge`` for ``world`` (k1 starts ``at``, "x,y,degrees");
    ``extra`` goes to the bridge. Yields the bridge once its world is alive."""
    with KheperaEmulator(body, EmulatorOptions(link_path=str(link))):
        bridge = lab.procs.start(
            "bridge",
            ["bridge", "--world", world, "--port", f"{link}=k1@{at}", *extra, *lab.net_args()],
        )
        lab.wait_alive(AliveKind.WORLD, world, bridge)
        yield bridge


def start_deploy(
    lab: ProcessLab, controller: Path, agent: str, user: str, *extra: str, ctx: str = CTX
) -> Proc:
    """``wart deploy`` of ``controller`` on ``agent`` as ``user`` (the test password);
    ``extra``: more of its options (``--dry-run``)."""
    return lab.procs.start(
        "deploy",
        [
            "deploy",
            str(controller),
            *extra,
            "--context",
            ctx,
            "--agent",
            agent,
            "--user",
            user,
            *lab.net_args(),
        ],
        env={"WART_PASSWORD": PASSWORD},
    )


def start_agent_context(
    lab: ProcessLab,
    *extra: str,
    slot: float = 2.5,
    ctx: str = CTX,
    world: str = WORLD,
    account: str = "ctx-arena",
) -> Proc:
    """The agent context ``ctx`` of ``world`` (a second one: another ``ctx`` and ``account``)."""
    return lab.start_agent_context(*extra, ctx=ctx, world=world, slot=slot, account=account)


class Poses:
    """The newest agent poses of the world, from its frames (callback kept short)."""

    def __init__(self, session: zenoh.Session, realm: str) -> None:
        self._raw: bytes | None = None
        self._lock = threading.Lock()
        self.count = 0
        rows: list[str] = []
        for reply in session.get(keys.world_snapshot(realm, WORLD), timeout=10.0):
            if reply.ok is not None:
                rows = decode(reply.ok.payload, WorldSnapshot).rows
        self.rows = rows

        def on(sample: zenoh.Sample) -> None:
            with self._lock:
                self._raw = bytes(sample.payload.to_bytes())
                self.count += 1

        self.sub = session.declare_subscriber(keys.world_frame(realm, WORLD), on)
        wait_for(lambda: self.count > 0, 10, "a world frame")

    def xy(self, agent: str) -> np.ndarray:
        with self._lock:
            raw = self._raw
        assert raw is not None
        frame = decode(raw, WorldFrame)
        return frame.poses.to_numpy()[self.rows.index(agent), :2].astype(float)

    def close(self) -> None:
        self.sub.undeclare()


class Motion:
    """Every frame's agent poses with the (monotonic) time it arrived: when did robots stop?

    A robot is at rest from the first frame from which on it moves less than
    ``eps`` mm a frame, for at least ``still`` frames in a row.
    """

    def __init__(self, session: zenoh.Session, realm: str, world: str = WORLD) -> None:
        rows: list[str] = []
        for reply in session.get(keys.world_snapshot(realm, world), timeout=10.0):
            if reply.ok is not None:
                rows = decode(reply.ok.payload, WorldSnapshot).rows
        self.rows = rows
        self._frames: deque[tuple[float, int, np.ndarray]] = deque(maxlen=2000)
        self._lock = threading.Lock()

        def on(sample: zenoh.Sample) -> None:
            at = time.monotonic()
            frame = decode(bytes(sample.payload.to_bytes()), WorldFrame)
            poses = frame.poses.to_numpy()[: len(self.rows), :2].astype(float)
            with self._lock:
                self._frames.append((at, frame.tick, poses))

        self.sub = session.declare_subscriber(keys.world_frame(realm, world), on)
        wait_for(lambda: self.frames_since(0.0), 10, "a world frame")

    def frames_since(self, t0: float) -> list[tuple[float, int, np.ndarray]]:
        with self._lock:
            return [f for f in self._frames if f[0] >= t0]

    def moving(self, agents: Sequence[str], t0: float, eps: float = 0.3) -> bool:
        """Whether every agent moved more than ``eps`` mm between two frames since ``t0``."""
        frames = self.frames_since(t0)
        if len(frames) < 2:
            return False
        idx = [self.rows.index(a) for a in agents]
        step = np.linalg.norm(frames[-1][2][idx] - frames[-2][2][idx], axis=1)
        return bool((step > eps).all())

    def at_rest_since(
        self, agents: Sequence[str], t0: float, eps: float = 0.05, still: int = 10
    ) -> float | None:
        """Arrival time of the first frame after ``t0`` from which every agent stays still."""
        frames = self.frames_since(t0)
        idx = [self.rows.index(a) for a in agents]
        run_start: float | None = None
        run = 0
        for before, after in itertools.pairwise(frames):
            step = np.linalg.norm(after[2][idx] - before[2][idx], axis=1)
            if (step < eps).all():
                if run == 0:
                    run_start = before[0]
                run += 1
            else:
                run, run_start = 0, None
        return run_start if run >= still else None

    def close(self) -> None:
        self.sub.undeclare()


@contextmanager
def agent_user(lab: ProcessLab, user: str, ctx: str = CTX) -> Iterator[AgentClient]:
    session = open_session(lab.router.options(), wait=10.0)
    try:
        with LabClient(session, lab.router.realm, lab.identity.verify_key) as client:
            client.login(user, PASSWORD)
            yield AgentClient(client, ctx).join()
    finally:
        close_session(session)


@contextmanager
def agent_users(lab: ProcessLab, *users: str) -> Iterator[list[AgentClient]]:
    """:func:`agent_user` for each of ``users``, in that order, all joined at once."""
    with ExitStack() as stack:
        yield [stack.enter_context(agent_user(lab, user)) for user in users]


def deploy_running(
    owners: dict[str, AgentClient], source: bytes, filename: str = "forward.py"
) -> dict[str, str]:
    """Each robot's owner queues ``source`` on it as a deployed controller; once every one
    runs, their request ids by robot."""
    rids = {
        agent: who.queue(agent, "deploy", source=source, filename=filename).request_id
        for agent, who in owners.items()
    }
    for agent, who in owners.items():
        assert who.wait_status(rids[agent], {"running"}, timeout=60), f"{agent} never ran"
    return rids
