"""Control-loop latency: a sensor sample's publication to the resulting command taking effect.

20 remote controllers (one Zenoh client process, one ZenohRobotLink per
agent, as the runner drives robots: all links share one WorldChannel, so each
tick's samples arrive in one SampleBundle and the commands leave in
CommandBundles; ``--per-agent``: each link on its agent's own keys, the path
``wart control`` uses for its one robot) react to every sensor sample of
their agent (the engine publishes at 50 Hz) with a sealed AgentCommand. The
engine runs in this process, instrumented: for each command it matches the
sample it answers (the controller echoes the sample's time in ``counters``)
and records

- *accepted*: sample published -> command verified against the lease by
  the engine (the network and security path);
- *applied*: sample published -> command applied to the world, at the
  engine's next tick (adds up to one 20 ms tick by design).

Beside it, in the same run and through the same router, two raw Zenoh round
trips at the same rate: between two client sessions of the world's process,
and over the loop's own path (the world's session -> the controllers'
process, which echoes -> back, express as the loop's publishers). The
target line judges p50 against 2x the path's round trip and p99 against 5 ms.

``--inline``: instead of one thread per controller, one function answers
every robot in the channel's own thread (``WorldChannel.on_tick``), as a
swarm controller would: no thread hand-off per robot, one message per tick.
``--swarm``: the same in the array API (``WorldChannel.on_swarm``: the
tick's decoded samples in, ``tick.send(agent, ...)`` out, without a
KheperaState and a RobotCommand per robot; the tick's commands leave as one
MacCommandBundle, each item MACed under its own agent's lease).

Against a peer (issue 22): the same loop written with plain zenoh-python
(bench/plain_peer.py: no login, lease or MAC; the same world, sample bundles
and command bundles, inline or threads as ours) runs in the same run, in
alternating blocks of ``--block`` seconds with our MAC round, so both see
the same machine load. Printed: both loops' figures, the ratio of their p50
and p99 (the target: within 1.3x and 1.5x), and the median over block pairs
of the p50 ratio, which other users' bursts move less. ``--no-peer`` leaves
it out (and ``--per-agent`` has no peer: the peer has no per-agent shape).

Two rounds on one engine that has an identity: *signed* (leases without
keys: every command an Ed25519 AuthEnvelope; ``--no-signed`` skips it) and
*MAC* (leases carrying the lease key sealed to each controller and to the
engine: MacCommands). Then
the per-command cost of the world's check (LeaseBook.check_command) and of
the sender's sealing, both paths, in this process; and the floor under N
controller threads in one process with no network at all (N threads handed
a sample at once, each decoding it and MACing a command). Run:

    .venv/bin/python -m bench.bench_control_latency [--controllers 20] [--seconds 10]
        [--inline | --swarm] [--block 0.5] [--no-peer] [--no-signed]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench import cli as bench_cli
from bench.control_child import child, grant
from bench.control_costs import command_costs, wake_storm
from bench.control_rounds import Round, measure, measure_against_peer
from bench.control_timing import TimedEngine, build_world, wait_ticking
from bench.control_verdicts import against_peer, pct, verdict
from bench.labproc import REPO, BenchLab
from bench.plain_peer import PEER_WORLD, PlainEngine
from common.auth import RegistryIdentity, issue_session
from common.service import close_session, open_session
from services.engine.service import EngineSettings


def _start_child(module: str, lab: BenchLab, inline: bool, *extra: str) -> subprocess.Popen[str]:
    """A controllers' process (ours or the plain peer's) on the lab's router, piped."""
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            module,
            *extra,
            "--realm",
            lab.realm,
            "--connect",
            lab.options.connect[0],
            *(["--inline"] if inline else []),
        ],
        cwd=REPO,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


def main() -> int:
    p = bench_cli.parser("bench_control_latency", __doc__)
    p.add_argument("--controllers", type=int, default=20)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument(
        "--processes",
        type=int,
        default=1,
        help="client processes the controllers are spread over (1: all 20 share one GIL, the "
        "pessimistic case; students' controllers really run on their own machines)",
    )
    p.add_argument(
        "--per-agent",
        action="store_true",
        help="each controller on its agent's own sensors and cmd keys (as wart control) instead "
        "of one shared WorldChannel (as the runner)",
    )
    p.add_argument(
        "--inline",
        action="store_true",
        help="one swarm function answers every robot in the channel's thread (WorldChannel."
        "on_tick) instead of one thread per controller: no hand-off, one message per tick",
    )
    p.add_argument(
        "--swarm",
        action="store_true",
        help="as --inline, but in the array API (WorldChannel.on_swarm: the tick's decoded "
        "samples in, tick.send(agent, ...) out, no per-robot KheperaState or RobotCommand, "
        "one MacCommandBundle a tick); the plain peer answers inline",
    )
    p.add_argument(
        "--block",
        type=float,
        default=0.5,
        help="seconds of each alternating block of ours (MAC) and the plain Zenoh peer",
    )
    p.add_argument(
        "--no-peer",
        action="store_true",
        help="leave out the plain Zenoh peer (the MAC round then runs alone, in one block)",
    )
    p.add_argument(
        "--no-signed", action="store_true", help="leave out the round of Ed25519-signed commands"
    )
    p.add_argument("--first", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--identity", help=argparse.SUPPRESS)
    p.add_argument("--realm", help=argparse.SUPPRESS)
    p.add_argument("--connect", help=argparse.SUPPRESS)
    args = p.parse_args()
    args.inline = args.inline or args.swarm  # the swarm answers in the channel's thread too
    if args.inline and args.per_agent:
        p.error("--inline answers in the shared WorldChannel's thread; it excludes --per-agent")
    if args.child:
        return child(args)
    # The peer's controllers answer from one subscriber (bundles): it has no per-agent shape.
    with_peer = not args.no_peer and not args.per_agent

    lab = BenchLab([], "unused")
    lab.start_router()
    ident_path = Path(tempfile.mkdtemp(prefix="wart-bench-")) / "registry.key"
    identity, _ = RegistryIdentity.load_or_create(ident_path)
    world_session = issue_session(identity, lab.realm, "engine-bench", ["world"])
    z = open_session(lab.options, wait=10)
    engine = TimedEngine(
        z,
        lab.realm,
        build_world(args.controllers),
        EngineSettings(tick_s=0.02, registry_key=identity.verify_key),
        identity=lambda: world_session,
    )
    engine.start()
    wait_ticking(engine.world)
    peer: PlainEngine | None = None
    peer_proc: subprocess.Popen[str] | None = None
    if with_peer:
        peer = PlainEngine(lab.options, build_world(args.controllers, PEER_WORLD))
        peer.start()
        wait_ticking(peer.world)
        peer_proc = _start_child(
            "bench.plain_peer", lab, args.inline, "--controllers", str(args.controllers)
        )
    count = max(1, min(args.processes, args.controllers))
    share = [
        args.controllers // count + (1 if i < args.controllers % count else 0) for i in range(count)
    ]
    procs = []
    first = 0
    for n in share:
        procs.append(
            _start_child(
                "bench.bench_control_latency",
                lab,
                args.inline,
                "--child",
                "--controllers",
                str(n),
                "--first",
                str(first),
                "--identity",
                str(ident_path),
                *(["--per-agent"] if args.per_agent else []),
                *(["--swarm"] if args.swarm else []),
            )
        )
        first += n
    results: dict[str, Round] = {}
    pids = {
        "router": [lab.procs[0].pid],
        "engine (and RTT probe)": [os.getpid()],
        "controllers": [p.pid for p in procs],
    }
    if peer_proc is not None:
        pids["engine (and RTT probe)"] = [os.getpid()]  # both engines: one process
        pids["peer's controllers"] = [peer_proc.pid]
    everyone = [*procs, *([peer_proc] if peer_proc is not None else [])]
    context = issue_session(identity, lab.realm, "ctx", ["lease"])
    try:
        holders = []
        for proc in procs:  # in index order: k0.. of the first, then the next's
            assert proc.stdout is not None
            holders += [
                (bytes.fromhex(h), bytes.fromhex(b)) for h, b in json.loads(proc.stdout.readline())
            ]
        if peer_proc is not None:
            assert peer_proc.stdout is not None
            if peer_proc.stdout.readline().strip() != "ready":
                raise RuntimeError("the plain peer's controllers did not start")
        for path in ("signed", "mac"):
            if path == "signed" and args.no_signed:
                continue
            leases = grant(
                z, context, lab.realm, holders, 3 * args.seconds, world_session, mac=path == "mac"
            )
            time.sleep(1.0)  # warm-up: subscriptions matched, leases in, JIT-free steady state
            for key, lease in leases:  # republished, as the context does
                z.put(key, context.seal(key, lease))
            time.sleep(1.0)
            if path == "mac" and peer is not None:
                results.update(
                    measure_against_peer(
                        engine, peer, z, lab.options, args.seconds, args.block, pids
                    )
                )
            else:
                results[path] = measure(engine, z, lab.options, args.seconds, pids)
        for proc in everyone:
            assert proc.stdin is not None
            proc.stdin.write("stop\n")
            proc.stdin.flush()
        for proc in everyone:
            proc.wait(20)
    finally:
        for proc in everyone:
            if proc.poll() is None:
                proc.kill()
        if peer is not None:
            peer.stop()
        engine.stop()
        close_session(z)
        lab.stop()
    n = sum(len(r.accepted) for r in results.values())
    print(
        f"engine: {engine.commands_accepted} accepted ({engine.leases.mac_accepted} MACed), "
        f"{engine.commands_refused} refused; {n} commands timed"
    )
    print(
        f"{args.controllers} remote controllers at 50 Hz in {count} client process(es), "
        + (
            "each on its own keys"
            if args.per_agent
            else "answering in the WorldChannel's thread in arrays (on_swarm)"
            if args.swarm
            else "answering in the WorldChannel's thread (on_tick)"
            if args.inline
            else "one thread each, sharing a WorldChannel"
        )
        + f", {args.seconds:g} s per path"
    )
    print(f"{'path':<44} {'p50 ms':>8} {'p99 ms':>8}")
    if peer is not None:
        print(
            f"plain Zenoh peer: {peer.commands} commands applied, {peer.refused} refused; "
            f"alternating blocks of {args.block:g} s with ours (MAC)"
        )
    names = {"signed": "signed", "mac": "MAC", "peer": "plain Zenoh peer's"}
    for path, (rtts, path_rtts, accepted, applied, cpu, _blocks) in results.items():
        rate = len(accepted) / args.seconds / max(1, args.controllers)
        print(f"-- {names[path]} commands ({len(accepted)}, {rate:.1f} Hz each)")
        print(f"{'raw Zenoh round trip (2 clients)':<44} {pct(rtts, 50):8.2f} {pct(rtts, 99):8.2f}")
        print(
            f"{'raw Zenoh round trip (world <-> controllers)':<44} "
            f"{pct(path_rtts, 50):8.2f} {pct(path_rtts, 99):8.2f}"
        )
        print(
            f"{'sample -> command accepted by engine':<44} "
            f"{pct(accepted, 50):8.2f} {pct(accepted, 99):8.2f}"
        )
        print(
            f"{'sample -> command applied (next tick)':<44} "
            f"{pct(applied, 50):8.2f} {pct(applied, 99):8.2f}"
        )
        print(
            "CPU per 20 ms tick: "
            + ", ".join(f"{role} {ms:.2f} ms" for role, ms in cpu.items())
            + f" (2 cores: {2 * 20} ms)"
        )
        print(verdict(accepted, rtts, path_rtts))
    if "peer" in results:
        print(against_peer(results["mac"], results["peer"]))
    command_costs()
    wake_storm(args.controllers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
