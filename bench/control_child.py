"""bench_control_latency's controllers' process (``--child``) and the leases granted to it.

``child`` runs in the process ``python -m bench.bench_control_latency --child``
starts: one ZenohRobotLink per agent, answering every sample (threads,
``--inline`` or ``--swarm``); ``grant`` is the agent context's side, in the
parent: a lease per agent, with MAC keys or without.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from bench.control_probes import PING, PONG
from bench.control_timing import WORLD
from common import keys
from common.auth import RegistryIdentity, Session, Verifier, issue_session
from common.controller import RobotCommand
from common.messages import Lease
from common.service import close_session, open_session
from common.world.leasemac import new_lease_key, seal_key
from common.world.remote_robot import SwarmTick, WorldChannel, ZenohRobotLink
from common.zconfig import NetworkOptions

T = TypeVar("T")


def _same(value: T) -> T:
    return value


def child(args: argparse.Namespace) -> int:
    """The controllers' process: one ZenohRobotLink per agent, answering every sample."""

    identity, _ = RegistryIdentity.load_or_create(Path(args.identity))
    options = NetworkOptions(realm=args.realm, connect=(args.connect,))
    z = open_session(options, wait=10)
    pong = z.declare_publisher(PONG, express=True)
    echo = z.declare_subscriber(PING, lambda s: pong.put(s.payload))  # for path_probe
    channel = None if args.per_agent else WorldChannel(z, args.realm, WORLD)
    indices = range(args.first, args.first + args.controllers)
    sessions = [issue_session(identity, args.realm, f"c{i}", ["control"]) for i in indices]
    holders = [[s.session_id.hex(), s.keys.box_public_key.hex()] for s in sessions]
    stop = threading.Event()
    verifier = Verifier(identity.verify_key, args.realm)  # to accept MAC leases
    links = [
        ZenohRobotLink(
            z,
            args.realm,
            WORLD,
            f"k{i}",
            functools.partial(_same, s),
            # Never due while the loop answers every tick; long, so that none goes out
            # during the plain peer's blocks either (it would load the peer's run).
            keepalive=30.0,
            verifier=verifier,
            channel=channel,
        )
        for i, s in zip(indices, sessions, strict=True)
    ]
    print(json.dumps(holders), flush=True)  # the links listen for their leases from here on

    def react(link: ZenohRobotLink) -> None:
        seen = 0
        while not stop.is_set():
            newest = link.wait_sample(seen, 0.5)
            if newest == seen:
                continue
            seen = newest
            link.send(RobotCommand(counters=(round(link.latest().time * 1000), 0)))

    if args.swarm:
        assert channel is not None

        def arrays(tick: SwarmTick) -> None:  # the same reaction, in the array API
            for agent, sample in zip(tick.agents, tick.samples, strict=True):
                tick.send(agent, counters=(round(sample.sim_time * 1000), 0))

        channel.on_swarm(arrays)
    elif args.inline:
        assert channel is not None
        by_agent = {link.agent: link for link in links}

        def swarm(_tick: int, agents: list[str]) -> None:
            for agent in agents:
                link = by_agent[agent]
                link.send(RobotCommand(counters=(round(link.latest().time * 1000), 0)))

        channel.on_tick(swarm)
    else:
        for link in links:
            threading.Thread(target=react, args=(link,), daemon=True).start()
    sys.stdin.readline()  # the parent says when to stop
    stop.set()
    for link in links:
        link.close(stop=False)
    print(
        f"client: {sum(x.mac_sent for x in links)} of {sum(x.sent for x in links)} commands MACed",
        file=sys.stderr,
    )
    if channel is not None:
        print(
            f"client: {channel.bundles} sample bundles in, {channel.commands} commands out "
            f"in {channel.puts} bundles",
            file=sys.stderr,
        )
        channel.close()
    echo.undeclare()
    pong.undeclare()
    close_session(z)
    return 0


def grant(
    z: Any,
    context: Session,
    realm: str,
    holders: list[tuple[bytes, bytes]],
    seconds: float,
    world: Session,
    *,
    mac: bool,
) -> list[tuple[str, Lease]]:
    """A lease per agent, as the agent context grants them: with MAC keys or without.

    Returns each lease and its key, to republish (sealed anew) as the context
    does every second: a subscriber declared just before the first put may
    not have reached the router yet, and would miss it.
    """
    now = time.time()
    out = []
    for i, (holder, box) in enumerate(holders):
        key = keys.agent_lease(realm, WORLD, f"k{i}")
        lease = Lease(
            lease_id=f"L{i}{'m' if mac else 's'}",
            world=WORLD,
            agent=f"k{i}",
            holder_user=f"c{i}",
            holder_session=holder,
            start=now,
            end=now + seconds + 60,
        )
        if mac:
            k = new_lease_key()
            lease = msgspec.structs.replace(
                lease,
                holder_key=seal_key(k, box),
                world_key=seal_key(k, world.keys.box_public_key),
                world_box=world.keys.box_public_key,
            )
        out.append((key, lease))
    for key, lease in out:
        z.put(key, context.seal(key, lease))
    return out
