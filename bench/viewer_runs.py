"""bench_viewer_sessions' two runs: the class on the in-memory lab, or on a real lab.

run_arena: one WebViewer in this process on the in-memory lab; run_real:
router, registry and engine as ``wart`` processes and ``--viewers`` viewer
processes. Each measures the viewer's CPU with nobody watching, then with
the class, and prints the RESULTS.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

from bench.labproc import BenchLab
from bench.viewer_class import ARENA, USERS, Child, _class_children, _merge, _print_sessions
from bench.viewer_cpu import _cpu_over, _proc_cpu
from common.keys import AliveKind
from tests.kit.procs import free_port
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoConnector, DemoLab

REPO = Path(__file__).resolve().parent.parent


def run_arena(args: argparse.Namespace, robots: int) -> None:
    load0 = os.getloadavg()
    print(
        f"arena of {robots} robots: {args.sessions} headless sessions, "
        f"{args.browsers} Chromium pages, load average {load0[0]:.2f}",
        flush=True,
    )
    lab = DemoLab("Bench lab", robots=robots, rate=args.world_rate)
    if robots > 1000:
        # The demo's 2 m arena would pile a big swarm on top of itself (10,000 discs
        # of 55 mm in 2 m: every pixel drawn a dozen times). Spread it as densely as
        # maps/swarm.json spreads its 1,000 robots (5 m square).
        from viewers.web.demo_lab import DemoWorld

        side = 5000.0 * math.sqrt(robots / 1000)
        lab.worlds[ARENA].stop()
        lab.worlds[ARENA] = DemoWorld(ARENA, robots, width=side, height=side, rate=args.world_rate)
    viewer = WebViewer(DemoConnector(("lab", lab)), port=free_port(), rate=args.rate)
    children: list[Child] = []
    try:
        idle, _ = _cpu_over(5.0)  # the fake world alone, no session
        url = f"127.0.0.1:{viewer.port}"
        children += _class_children(
            args, [f"ws://{url}"], f"http://{url}", USERS, "127.0.0.1", ARENA
        )
        for child in children:
            child.ready.wait(900)
            if child.proc.poll() is not None and child.result is None:
                raise RuntimeError(f"{child.name} ended early:\n" + "\n".join(child.tail))
        sessions = len(viewer.sessions)
        views = [s.view for s in viewer.sessions.values()]
        applied0 = [v.frames_applied for v in views]
        busy0 = viewer.pump.busy_s
        for child in children:
            child.go()
        loaded, threads = _cpu_over(args.seconds)
        busy = (viewer.pump.busy_s - busy0) / args.seconds
        applied = [
            (v.frames_applied - a) / args.seconds for v, a in zip(views, applied0, strict=True)
        ]
        results = {c.name: c.finish(120) for c in children}
    finally:
        for child in children:
            child.kill()
        viewer.stop()
        lab.close()
    load1 = os.getloadavg()
    head = results["headless"]
    per_session = 100 * (loaded - idle) / max(1, sessions)
    print(
        f"RESULTS arena of {robots} robots, {sessions} sessions, {args.seconds:.0f} s, "
        f"pump {args.rate:.0f} Hz, world {args.world_rate:.0f} Hz"
    )
    _print_sessions(args, head, results)
    print(f"  server applied per view: min {min(applied):.1f} max {max(applied):.1f} frames/s")
    print(
        f"  viewer process CPU: {100 * loaded:.1f} % of a core with sessions, "
        f"{100 * idle:.1f} % without (fake world); {per_session:.2f} % of a core per session"
    )
    busiest = ", ".join(f"{n} {100 * v:.0f} %" for n, v in threads.items())
    print(f"  busiest threads (CPU, % of a core): {busiest}")
    print(
        f"  pump thread busy (wall): {100 * busy:.1f} % of a core; "
        f"headless clients' process: {100 * head['client_cpu']:.0f} % of a core"
    )
    if head["errors"]:
        print(f"  client errors: {head['errors']}")
    print(
        f"  load average before {load0[0]:.2f}, after {load1[0]:.2f}; {os.cpu_count()} CPUs",
        flush=True,
    )


REAL_PASSWORD = "class-of-2026"


def _class_map(path: Path, robots: int) -> None:
    """maps/swarm.json with ``robots`` Khepera on its grid (spread wider past 1,000)."""
    spec = json.loads((REPO / "maps" / "swarm.json").read_text())
    group = spec["agent_groups"][0]
    group["count"] = robots
    if robots > 1000:
        scale = math.sqrt(robots / 1000)
        spec["arena"] = {"width": 5000 * scale, "height": 5000 * scale}
        group["area"] = [c * scale for c in group["area"]]
    path.write_text(json.dumps(spec))


def run_real(args: argparse.Namespace, robots: int) -> None:
    """The class on a real lab: router, registry and engine as ``wart`` processes, and
    ``--viewers`` viewer processes on the same lab, each serving its share of the class
    (a student's address can name any of them)."""

    users = [("ana", REAL_PASSWORD), ("ben", REAL_PASSWORD)]
    load0 = os.getloadavg()
    print(
        f"real lab, arena of {robots} robots: {args.sessions} headless sessions over "
        f"{args.viewers} viewer processes, {args.browsers} Chromium pages, "
        f"load average {load0[0]:.2f}",
        flush=True,
    )
    lab = BenchLab([u for u, _ in users], REAL_PASSWORD)
    children: list[Child] = []
    try:
        lab.start()
        _class_map(lab.tmp / "class.json", robots)
        engine = ["engine", "--map", str(lab.tmp / "class.json"), "--world", ARENA, "--wander"]
        engine += ["--maps-dir", str(lab.tmp)]
        lab.spawn(
            [*engine, *lab.net()],
            (AliveKind.WORLD, ARENA),
        )
        pids = {"engine": lab.procs[-1].pid, "router": lab.procs[0].pid}
        ports = []
        for i in range(args.viewers):
            ports.append(free_port())
            viewer = ["viewer", "--http-port", str(ports[-1]), "--id", f"web{i}"]
            viewer += ["--data-dir", str(lab.tmp / f"web{i}"), "--rate", str(args.rate)]
            lab.spawn([*viewer, *lab.net()], (AliveKind.VIEWER, f"web{i}"))
            pids[f"viewer {i}"] = lab.procs[-1].pid
            print(f"  viewer {i} on http://127.0.0.1:{ports[-1]}", flush=True)
        idle = _proc_cpu(pids, 5.0)  # the lab with nobody watching
        address = f"127.0.0.1:{lab.port}/{lab.realm}"
        children = _class_children(
            args,
            [f"ws://127.0.0.1:{port}" for port in ports],
            f"http://127.0.0.1:{ports[0]}",
            users,
            address,
            ARENA,
        )
        for child in children:
            child.ready.wait(1800)
            if child.proc.poll() is not None and child.result is None:
                raise RuntimeError(f"{child.name} ended early:\n" + "\n".join(child.tail))
        for child in children:
            child.go()
        loaded = _proc_cpu(pids, args.seconds)
        results = {c.name: c.finish(120) for c in children}
    finally:
        for child in children:
            child.kill()
        lab.stop()
    load1 = os.getloadavg()
    head = _merge([r for n, r in results.items() if n.startswith("headless")])
    print(
        f"RESULTS real lab, arena of {robots} robots, {args.sessions} sessions over "
        f"{args.viewers} viewers, {args.seconds:.0f} s, pump {args.rate:.0f} Hz"
    )
    for name, r in sorted(results.items()):
        if name.startswith("headless") and len(results) > 1:
            fr = r["frames"]
            print(
                f"  {name}: {r['sessions']} sessions, min {fr['min']:.1f} "
                f"mean {fr['mean']:.1f} max {fr['max']:.1f} updates/s"
            )
    _print_sessions(args, head, results)
    sessions = args.sessions + args.browsers
    viewer_cpu = sum(v - idle[n] for n, v in loaded.items() if n.startswith("viewer"))
    for name in pids:
        print(
            f"  {name} CPU: {100 * loaded[name]:.1f} % of a core "
            f"({100 * idle[name]:.1f} % with nobody watching)"
        )
    print(
        f"  viewers' CPU for the class: {100 * viewer_cpu:.1f} % of a core, "
        f"{100 * viewer_cpu / max(1, sessions):.2f} % per session; headless clients' "
        f"processes: {100 * head['client_cpu']:.0f} % of a core"
    )
    if head["errors"]:
        print(f"  client errors: {head['errors']}")
    if head["retried"]:
        print(f"  in on a second try ({len(head['retried'])}): {head['retried'][:3]}")
    if head["failed"]:
        print(f"  could not get in ({len(head['failed'])}): {head['failed'][:3]}")
    print(
        f"  load average before {load0[0]:.2f}, after {load1[0]:.2f}; {os.cpu_count()} CPUs",
        flush=True,
    )
