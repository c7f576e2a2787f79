"""bench_control_latency's micro-benchmarks, in this process, without the network.

command_costs: the per-command cost of the world's check and the sender's
sealing, signed and MAC; wake_storm: the floor under N controller threads
woken at once in one process.
"""

from __future__ import annotations

import functools
import threading
import time

import numpy as np

from bench.control_timing import WORLD
from bench.swarm_bundle_cost import sample
from common import keys
from common.auth import RegistryIdentity, Verifier, issue_session
from common.controller import RobotCommand
from common.messages import AgentCommand, SensorSample, decode, encode
from common.world.leasemac import WorldBoxKeys, mac_command, new_lease_key
from common.world.leases import LeaseBook
from common.world.remote_robot import agent_command, state_from_sample
from tests.kit.leases import mac_lease


def _past(counts: list[int], i: int, seen: int) -> bool:
    return counts[i] > seen


def command_costs(n: int = 5000) -> None:
    """Per-command cost of the world's check and the sender's sealing, both paths."""
    identity = RegistryIdentity.generate()
    realm = "bench"
    holder = issue_session(identity, realm, "c0", ["control"])
    world = issue_session(identity, realm, "engine-bench", ["world"])
    context = issue_session(identity, realm, "ctx", ["lease"])

    book = LeaseBook(
        realm, WORLD, Verifier(identity.verify_key, realm), WorldBoxKeys(lambda: world)
    )
    k = new_lease_key()
    now = time.time()
    lease = mac_lease(
        k, holder, world, lease_id="L0", world_name=WORLD, agent="k0", start=now, end=now + 600
    )
    lkey = keys.agent_lease(realm, WORLD, "k0")
    book.accept_lease(lkey, context.seal(lkey, lease))
    ckey = keys.agent_cmd(realm, WORLD, "k0")
    command = AgentCommand(agent="k0", speeds=(10, 10))
    t0 = time.perf_counter()
    signed = [holder.seal(ckey, command) for _ in range(n)]
    t1 = time.perf_counter()
    maced = [mac_command(k, ckey, "L0", i + 1, command, time.time()) for i in range(n)]
    t2 = time.perf_counter()
    for payload in signed:
        book.check_command(ckey, payload)
    t3 = time.perf_counter()
    for payload in maced:
        book.check_command(ckey, payload)
    t4 = time.perf_counter()
    us = 1e6 / n
    print(f"per command, one core, {n} each (LeaseBook.check_command: decode, auth, lease):")
    print(
        f"  signed (Ed25519 AuthEnvelope): world {(t3 - t2) * us:6.1f} µs, "
        f"sender {(t1 - t0) * us:6.1f} µs, {len(signed[0])} bytes"
    )
    print(
        f"  MAC (keyed BLAKE2b MacCommand): world {(t4 - t3) * us:6.1f} µs, "
        f"sender {(t2 - t1) * us:6.1f} µs, {len(maced[0])} bytes"
    )


def wake_storm(n: int, rounds: int = 200) -> None:
    """The floor under n controller threads in one process, without any network.

    One thread hands n waiting threads a sample each, as the client's Zenoh
    callback does; each wakes, decodes it and MACs a command (the bench's
    reaction, minus the put). Printed: when the median and the last thread
    are done, after the hand-out began.
    """

    raw = encode(sample("k0", WORLD))
    key, cmd_key = new_lease_key(), keys.agent_cmd("bench", WORLD, "k0")
    fresh = [threading.Condition() for _ in range(n)]
    handed = [0] * n
    done = [0.0] * n
    stop = False

    def react(i: int) -> None:
        seen = 0
        while not stop:
            with fresh[i]:
                fresh[i].wait_for(functools.partial(_past, handed, i, seen), 0.5)
                if handed[i] == seen:
                    continue
                seen = handed[i]
            state = state_from_sample(decode(raw, SensorSample))
            command = agent_command("k0", RobotCommand(counters=(round(state.time * 1000), 0)))
            mac_command(key, cmd_key, "L0", seen, command, time.time())
            done[i] = time.perf_counter()

    threads = [threading.Thread(target=react, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    spans = []
    for _ in range(rounds):
        start = time.perf_counter()
        for i in range(n):
            with fresh[i]:
                handed[i] += 1
                fresh[i].notify_all()
        time.sleep(0.02)
        ends = sorted(done)
        spans.append((ends[n // 2] - start, ends[-1] - start))
    stop = True
    median = np.median(np.array(spans[rounds // 10 :]) * 1000, axis=0)
    print(
        f"{n} controller threads woken at once, no network: median thread done after "
        f"{median[0]:.2f} ms, last after {median[1]:.2f} ms (p50 over {rounds} rounds)"
    )
