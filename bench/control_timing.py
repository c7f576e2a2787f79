"""bench_control_latency's instrumented engine: when each sample went out, each command came in.

TimedEngine records, per command answering a sample, *accepted* (sample
published -> command verified against the lease) and *applied* (sample
published -> command applied at the next tick); build_world and
wait_ticking make and warm up the worlds it and the plain peer step.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from common.sim2d.agents import agent_type
from common.sim2d.world import World
from services.engine.service import EngineService, _Command

WORLD = "bench"


class TimedEngine(EngineService):
    """The engine, recording when each sample was published and each command arrived."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.published: dict[tuple[str, int], float] = {}  # (agent, sample ms) -> put time
        self.accepted: list[float] = []
        self.applied: list[float] = []
        self.recording = False
        self.bundled: list[str] = []  # the agents of the sample bundle being put
        # Cleared while the plain peer's block runs: every tick's work but the samples' put.
        self.publishing = threading.Event()
        self.publishing.set()

    def _publish(self) -> None:
        for agent, pub in list(self._agent_pubs.items()):
            if not isinstance(pub, _TimedPublisher):
                self._agent_pubs[agent] = _TimedPublisher(pub, agent, self)
        if not isinstance(self._samples_pub, _TimedBundles):
            self._samples_pub = _TimedBundles(self._samples_pub, self)
        super()._publish()

    def publish_sample_bundle(self, tick: int, samples: dict[str, bytes]) -> None:
        # The agents the bundle carries, for _TimedBundles: decoding the bundle after
        # its put (as before) was work only our engine did right after the put.
        self.bundled = list(samples)
        super().publish_sample_bundle(tick, samples)

    def _apply(self, item: _Command) -> None:
        now = time.monotonic()
        super()._apply(item)
        counters = item.command.counters
        if counters is None or not self.recording:
            return
        sent = self.published.get((item.agent, counters[0]))
        if sent is not None:
            self.accepted.append(item.received - sent)
            self.applied.append(now - sent)


class _TimedPublisher:
    """An agent's sensor publisher that notes when each sample went out."""

    def __init__(self, pub: Any, agent: str, engine: TimedEngine) -> None:
        self.pub, self.agent, self.engine = pub, agent, engine

    def put(self, payload: bytes) -> None:
        if not self.engine.publishing.is_set():
            return
        ms = round(self.engine.world.sim_time * 1000)
        self.engine.published[(self.agent, ms)] = time.monotonic()
        self.pub.put(payload)

    def undeclare(self) -> None:
        self.pub.undeclare()


class _TimedBundles:
    """The world's sample-bundle publisher, noting when each agent's sample went out."""

    def __init__(self, pub: Any, engine: TimedEngine) -> None:
        self.pub, self.engine = pub, engine

    @property
    def matching_status(self) -> Any:
        return self.pub.matching_status

    def put(self, payload: bytes) -> None:
        if not self.engine.publishing.is_set():
            return
        sent = time.monotonic()
        self.pub.put(payload)
        ms = round(self.engine.world.sim_time * 1000)
        for agent in self.engine.bundled:  # after the put: not timed
            self.engine.published[(agent, ms)] = sent

    def undeclare(self) -> None:
        self.pub.undeclare()


def build_world(n: int, name: str = WORLD) -> World:
    world = World(2000, 2000, seed=1, tick_s=0.02, name=name)
    spec = agent_type("khepera")
    for i in range(n):
        world.add_agent(f"k{i}", spec, 150 + (i % 5) * 300, 150 + (i // 5) * 300, 0.0)
    return world


def wait_ticking(world: World, timeout: float = 300.0) -> None:
    """Until ``world`` has stepped a few ticks: its first step compiles the kernels (numba),
    which takes seconds, longer on a loaded machine; nothing is measured before that."""
    deadline = time.monotonic() + timeout
    while world.tick < 10:
        if time.monotonic() > deadline:
            raise RuntimeError(f"world {world.name} did not start ticking in {timeout:g} s")
        time.sleep(0.05)
