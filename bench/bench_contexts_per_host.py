"""How many simulated arenas of 10 Khepera a host keeps at real time (issue 8).

    .venv/bin/python -m bench.bench_contexts_per_host [--max 12] [--window 6]

Part 1, one host with both cores: a router and engines (``wart engine`` on a
copy of maps/foraging.json with 10 Khepera, the arena's processes as ``wart
host`` starts them) are added one at a time; after each, every world's
real-time factor (simulated seconds per wall second, from its frames) is
measured over --window seconds, with the engines' resident memory. The host
"keeps" N arenas while the slowest of them stays at or above 0.95.

Part 2, hosts as network namespaces (root only): the same, with two hosts
each pinned to ONE core (taskset), against one such host alone, to show that
capacity adds up when arenas spread over hosts. (Namespaces do not split the
CPU; the pinning does, so a "host" here is one core of this machine.)

Other engineers share this machine: read the figures with its load average,
which the script prints.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

from bench import cli as bench_cli
from common import keys
from common.messages import WorldFrame, decode
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.lab.lab_maps import map_with_robots
from tests.kit import netns

REPO = Path(__file__).resolve().parent.parent

REALM = "benchhost"
REAL_TIME = 0.95


def measure(
    endpoint: str, worlds: list[str], window: float, sensors: bool = False
) -> dict[str, float]:
    """Each world's real-time factor over ``window`` seconds, seen from ``endpoint``.

    With ``sensors`` it also subscribes to every world's sensor batch, so the
    engines sense and publish each tick, as for an arena whose robots are driven.
    """
    session = open_session(NetworkOptions(realm=REALM, connect=(endpoint,)), wait=10.0, quiet=True)
    first: dict[str, tuple[float, float]] = {}
    last: dict[str, tuple[float, float]] = {}
    lock = threading.Lock()

    def on_frame(sample: object) -> None:
        frame = decode(sample.payload, WorldFrame)  # type: ignore[attr-defined]
        now = time.monotonic()
        with lock:
            first.setdefault(frame.world, (now, frame.sim_time))
            last[frame.world] = (now, frame.sim_time)

    subs = [session.declare_subscriber(keys.world_frame(REALM, w), on_frame) for w in worlds]
    if sensors:
        subs += [
            session.declare_subscriber(keys.world_sensors(REALM, w), lambda _s: None)
            for w in worlds
        ]
    time.sleep(window)
    for sub in subs:
        sub.undeclare()
    close_session(session)
    factors = {}
    for w in worlds:
        if w not in first or last[w][0] - first[w][0] < window / 2:
            factors[w] = 0.0
            continue
        factors[w] = (last[w][1] - first[w][1]) / (last[w][0] - first[w][0])
    return factors


def engine_argv(map_path: Path, world: str, endpoint: str) -> list[str]:
    return [
        "-m", "services.cli", "engine", "--map", str(map_path), "--world", world,
        "--realm", REALM, "--connect", endpoint, "--no-multicast-scouting",
    ]  # fmt: skip


def wait_frames(prefix: list[str], endpoint: str, world: str, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if measure_in(prefix, endpoint, [world], 1.0).get(world, 0) > 0:
            return
    raise RuntimeError(f"{world} published no frames in {timeout:.0f} s")


def run_host(
    label: str,
    hosts: list[tuple[list[str], str]],
    map_path: Path,
    args: argparse.Namespace,
) -> dict[str, object]:
    """Add arenas round-robin over ``hosts`` (each: command prefix, router endpoint)."""
    procs: list[subprocess.Popen[bytes]] = []
    routers: list[subprocess.Popen[bytes]] = []
    rows = []
    kept = 0
    try:
        for prefix, endpoint in hosts:
            listen = (
                endpoint.replace("127.0.0.1", "0.0.0.0") if "127.0.0.1" in endpoint else endpoint
            )
            routers.append(subprocess.Popen(
                [*prefix, sys.executable, "-m", "services.cli", "router", "--realm", REALM,
                 "--listen", listen, "--no-multicast-scouting"],
                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True,
            ))  # fmt: skip
        time.sleep(1.5)
        worlds: list[tuple[str, str]] = []
        for n in range(1, args.max + 1):
            prefix, endpoint = hosts[(n - 1) % len(hosts)]
            world = f"a{n}"
            procs.append(subprocess.Popen(
                [*prefix, sys.executable, *engine_argv(map_path, world, endpoint)],
                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True,
            ))  # fmt: skip
            worlds.append((world, endpoint))
            wait_frames(prefix, endpoint, world)
            factors: dict[str, float] = {}
            # A dip below real time is measured again once before it counts: the
            # machine is shared, and another engineer's burst is not our limit.
            for _attempt in range(2):
                factors = {}
                for _, ep in hosts:
                    mine = [w for w, e in worlds if e == ep]
                    if mine:
                        factors.update(
                            measure_in(prefix_of(hosts, ep), ep, mine, args.window, args.sensors)
                        )
                if min(factors.values()) >= REAL_TIME:
                    break
            rss = []
            for p in procs:  # `ip netns exec` and `taskset` exec: the pid is the engine
                with contextlib.suppress(psutil.Error):
                    rss.append(psutil.Process(p.pid).memory_info().rss / 2**20)
            slowest = min(factors.values())
            row = {
                "arenas": n, "slowest_rt": round(slowest, 3),
                "mean_rt": round(sum(factors.values()) / len(factors), 3),
                "engine_rss_mb": round(sum(rss) / len(rss), 1),
                "load1": round(os.getloadavg()[0], 2),
            }  # fmt: skip
            rows.append(row)
            print(f"  {label}: {json.dumps(row)}", flush=True)
            if slowest >= REAL_TIME:
                kept = n
            else:
                break
    finally:
        for p in procs + routers:
            try:
                os.killpg(p.pid, 15)
                p.wait(10)
            except (ProcessLookupError, subprocess.TimeoutExpired):
                os.killpg(p.pid, 9)
    return {"label": label, "kept_at_real_time": kept, "rows": rows}


def prefix_of(hosts: list[tuple[list[str], str]], endpoint: str) -> list[str]:
    return next(prefix for prefix, ep in hosts if ep == endpoint)


def measure_in(
    prefix: list[str], endpoint: str, worlds: list[str], window: float, sensors: bool = False
) -> dict[str, float]:
    """Measure from inside the host's namespace when there is one (the prefix says)."""
    netns_prefix = prefix[:4] if prefix[:3] == ["ip", "netns", "exec"] else []
    if not netns_prefix:
        return measure(endpoint, worlds, window, sensors)
    out = subprocess.run(
        [*netns_prefix, sys.executable, "-m", "bench.bench_contexts_per_host",
         "--measure", endpoint, "--window", str(window),
         *(["--sensors"] if sensors else []), *worlds],
        cwd=REPO, capture_output=True, text=True, timeout=window + 60,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    p = bench_cli.parser("bench_contexts_per_host", __doc__)
    p.add_argument("--max", type=int, default=12, help="most arenas to try")
    p.add_argument("--window", type=float, default=6.0, help="seconds measured after each arena")
    p.add_argument("--robots", type=int, default=10)
    p.add_argument("--skip-netns", action="store_true")
    p.add_argument("--skip-single", action="store_true", help="only the two-host part")
    p.add_argument("--sensors", action="store_true", help="also consume every sensor batch")
    p.add_argument("--measure", help=argparse.SUPPRESS)
    p.add_argument("worlds", nargs="*", help=argparse.SUPPRESS)
    args = p.parse_args()
    # SIGTERM runs the finally blocks too, so no engine or namespace is left behind.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))
    if args.measure:  # the helper run inside a namespace
        print(json.dumps(measure(args.measure, args.worlds, args.window, args.sensors)))
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="wart-bench-hosts-"))
    map_path = map_with_robots(REPO / "maps" / "foraging.json", args.robots, tmp / "ten.json")
    print(f"cores {os.cpu_count()}, load average at start {os.getloadavg()} (shared machine)")
    results = []
    if not args.skip_single:
        results.append(run_host("one host, 2 cores", [([], "tcp/127.0.0.1:17911")], map_path, args))
    if not args.skip_netns:
        reason = netns.available()
        if reason:
            print(f"two-host part skipped: {reason}")
        else:
            with netns.Network(2) as net:
                a, b = net.hosts
                one = [
                    (["ip", "netns", "exec", a.name, "taskset", "-c", "0"], f"tcp/{a.address}:7447")
                ]
                two = [
                    *one,
                    (
                        ["ip", "netns", "exec", b.name, "taskset", "-c", "1"],
                        f"tcp/{b.address}:7447",
                    ),
                ]
                results.append(run_host("one netns host, 1 core", one, map_path, args))
                results.append(run_host("two netns hosts, 1 core each", two, map_path, args))
    print(
        "RESULT " + json.dumps([{k: r[k] for k in ("label", "kept_at_real_time")} for r in results])
    )
    (tmp / "results.json").write_text(json.dumps(results, indent=1))
    print(f"details in {tmp / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
