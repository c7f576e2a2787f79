"""Web viewer benchmark: 100 sessions on one arena (issue 22).

This process runs one WebViewer on the in-memory lab (an arena of --robots
robots whose frames come at --world-rate Hz) and nothing else, so its CPU
time is the viewer's (plus the fake world's thread: measured alone first,
with no session, and subtracted). Two child processes stand for the class:

- ``--as-clients``: --sessions headless websocket clients speaking viser's
  protocol (tests/viser_client.py): each connects, logs in through the GUI
  (Connect, User, Password, Log in), joins the arena, then counts the robot
  frames and bytes it receives;
- ``--as-browsers``: --browsers real Chromium pages (Playwright, software
  WebGL) logged in and watching the same arena, frames counted from
  Playwright's websocket events.

Once both say READY the parent says GO; everyone measures the same
--seconds. Printed per arena: updates/s per session (min, mean, max; headless
and Chromium apart), server CPU per session (the viewer's process CPU time
with sessions minus without, over the number of sessions), bytes/s per
session, the pump's busy share, and the machine's load average.

    PYTHONPATH=. .venv/bin/python -m bench.bench_viewer_sessions --robots 35 1000
    PYTHONPATH=. .venv/bin/python -m bench.bench_viewer_sessions --robots 10000 --sessions 10

With --slow K, K of the headless clients read their socket only every
--slow-every seconds (a saturated link, a frozen tab): they should get fewer
frames and the others as many as without them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

USERS = [("ana", "ana-pw"), ("ben", "ben-pw")]
ARENA = "arena"


def _stats(values: list[float]) -> dict[str, float]:
    if not values:
        return {"min": 0.0, "mean": 0.0, "max": 0.0}
    return {"min": min(values), "mean": sum(values) / len(values), "max": max(values)}


# -- the headless clients (a child process) ------------------------------------------------


async def _clients(
    urls: list[str],
    sessions: int,
    seconds: float,
    slow: int,
    slow_every: float,
    users: list[tuple[str, str]],
    arena: str,
) -> None:
    from tests.viser_client import ViserClient

    # A student's address may name any viewer: sessions are dealt round the viewers.
    clients = [ViserClient(urls[i % len(urls)], f"s{i}") for i in range(sessions)]
    gate = asyncio.Semaphore(10)  # a class logging in within a minute, ten at a time
    done = 0

    failed: list[str] = []
    retried: list[str] = []  # told "could not log in" once, in on their second try

    async def enter(i: int, client: ViserClient) -> None:
        try:
            await enter_once(i, client)
        except (TimeoutError, ConnectionError, OSError) as exc:
            # One student who cannot get in is a finding, not the end of the run.
            failed.append(f"{client.name}: {exc}"[:300])
            print(f"PROGRESS {client.name} could not get in: {exc}"[:300], flush=True)

    async def enter_once(i: int, client: ViserClient) -> None:
        nonlocal done
        async with gate:
            # A slow reader's own kernel buffer is kept small (16 KiB): its link, not
            # its kernel, is where the bytes would wait; with Linux's default a client
            # that reads once a second still takes every frame into its kernel.
            if i < slow:
                await client.connect(max_queue=1, rcvbuf=16 * 1024)
            else:
                await client.connect()
            user, password = users[i % len(users)]
            try:
                await client.log_in(user, password, timeout=120)
            except ConnectionError as exc:
                if "Could not log in" not in str(exc):
                    raise
                # The page said why and to try again (a busy lab): a student does.
                retried.append(f"{client.name}: {exc}"[:300])
                await client.log_in(user, password, timeout=120)
            await client.join(arena, timeout=120)
        done += 1
        if done % 10 == 0 or done == sessions:
            print(f"PROGRESS {done}/{sessions} headless sessions watch the arena", flush=True)

    started = time.monotonic()
    await asyncio.gather(*(enter(i, c) for i, c in enumerate(clients)))
    print(f"PROGRESS all in after {time.monotonic() - started:.1f} s", flush=True)

    async def slow_reader(client: ViserClient) -> None:
        while True:
            client.stall()
            await asyncio.sleep(slow_every)
            client.resume()
            await asyncio.sleep(0.05)

    out = {f.split(":", 1)[0] for f in failed}
    everyone = clients
    clients = [c for c in everyone if c.name not in out]  # who got in is measured
    slow = len([c for c in everyone[:slow] if c.name not in out])
    sessions = len(clients)
    slowed = [asyncio.get_running_loop().create_task(slow_reader(c)) for c in clients[:slow]]
    print("READY", flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)  # GO
    f0 = [c.frames for c in clients]
    b0 = [c.bytes for c in clients]
    t0 = time.monotonic()
    cpu0 = time.process_time()
    while (left := t0 + seconds - time.monotonic()) > 0:
        await asyncio.sleep(min(5.0, left))
        rates = [(c.frames - f) / (time.monotonic() - t0) for c, f in zip(clients, f0, strict=True)]
        s = _stats(rates[slow:])
        print(
            f"PROGRESS {time.monotonic() - t0:.0f} s: frames/s per session "
            f"min {s['min']:.1f} mean {s['mean']:.1f} max {s['max']:.1f}",
            flush=True,
        )
    elapsed = time.monotonic() - t0
    frames = [(c.frames - f) / elapsed for c, f in zip(clients, f0, strict=True)]
    mbytes = [(c.bytes - b) / elapsed / 1e6 for c, b in zip(clients, b0, strict=True)]
    cpu = time.process_time() - cpu0
    for task in slowed:
        task.cancel()
    errors = [f"{c.name}: {c.error}" for c in clients if c.error is not None]
    result = {
        "frames": _stats(frames[slow:]),
        "slow_frames": _stats(frames[:slow]),
        "mb": _stats(mbytes[slow:]),
        "client_cpu": cpu / elapsed,
        "errors": errors[:5],
        "sessions": sessions - slow,
        "slow": slow,
        "failed": failed,
        "retried": retried,
    }
    print("RESULT " + json.dumps(result), flush=True)
    await asyncio.gather(*(c.close() for c in everyone))


# -- the Chromium pages (a child process) ---------------------------------------------------


def _browsers(
    url: str, count: int, seconds: float, users: list[tuple[str, str]], address: str, arena: str
) -> None:
    from playwright.sync_api import sync_playwright

    from bench.bench_viewer import BENCH_VIEWPORT, WsCounter
    from tests.browser.conftest import CHROMIUM_ARGS, ViserPage
    from viewers.web.address import parse_address

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        pages, counters = [], []
        for i in range(count):
            page = browser.new_context(viewport=BENCH_VIEWPORT).new_page()
            counter = WsCounter()
            counter.attach(page)
            page.goto(url)
            vp = ViserPage(page, f"sessions-{i}")
            vp.wait_ready(120_000)
            user, password = users[i % len(users)]
            vp.log_in(address, user, password)
            vp.tab(parse_address(address, default_realm="lab").label).first.click()
            vp.click(f"Join {arena}", timeout=120_000)
            pages.append(vp)
            counters.append(counter)
            print(f"PROGRESS Chromium page {i + 1}/{count} watches the arena", flush=True)
        if pages:
            pages[0].p.wait_for_timeout(2000)
        print("READY", flush=True)
        sys.stdin.readline()  # GO
        s0 = [c.read() for c in counters]
        t0 = time.monotonic()
        if pages:
            pages[0].p.wait_for_timeout(seconds * 1000)  # events arrive only inside Playwright
        else:
            time.sleep(seconds)
        elapsed = time.monotonic() - t0
        s1 = [c.read() for c in counters]
        # Is the page still usable? Animation frames it painted in 3 s (the
        # canvas redraws in one; a page stuck in work paints few).
        fps = [float(vp.p.evaluate(RAF_COUNT)) / 3.0 for vp in pages]
        browser.close()
    frames = [(b["messages"] - a["messages"]) / elapsed for a, b in zip(s0, s1, strict=True)]
    mb = [(b["bytes"] - a["bytes"]) / elapsed / 1e6 for a, b in zip(s0, s1, strict=True)]
    result = {"frames": _stats(frames), "mb": _stats(mb), "paint_fps": _stats(fps)}
    print("RESULT " + json.dumps(result), flush=True)


RAF_COUNT = """() => new Promise(done => {
  let n = 0; const end = performance.now() + 3000;
  const step = t => { n += 1; if (t < end) requestAnimationFrame(step); else done(n); };
  requestAnimationFrame(step);
})"""


# -- the viewer (this process) ---------------------------------------------------------------


class Child:
    """A child process whose PROGRESS lines are relayed and whose RESULT is kept."""

    def __init__(self, name: str, args: list[str]) -> None:
        env = dict(os.environ)
        env["PYTHONPATH"] = str(Path(__file__).resolve().parent.parent)
        self.name = name
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.bench_viewer_sessions", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.ready = threading.Event()
        self.result: dict[str, Any] | None = None
        self.tail: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        out: IO[str] | None = self.proc.stdout
        assert out is not None
        for line in out:
            line = line.rstrip()
            self.tail = [*self.tail[-30:], line]
            if line.startswith("PROGRESS "):
                print(f"  [{self.name}] {line[9:]}", flush=True)
            elif line == "READY":
                self.ready.set()
            elif line.startswith("RESULT "):
                self.result = json.loads(line[7:])
        self.ready.set()  # ended: nobody waits for ever

    def go(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("GO\n")
        self.proc.stdin.flush()

    def finish(self, timeout: float) -> dict[str, Any]:
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        if self.result is None:
            raise RuntimeError(f"{self.name} gave no result:\n" + "\n".join(self.tail))
        return self.result

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


def _class_children(
    args: argparse.Namespace,
    ws_urls: list[str],
    http_url: str,
    users: list[tuple[str, str]],
    address: str,
    arena: str,
) -> list[Child]:
    """The class: headless clients (one process per viewer, sessions dealt round the
    viewers) and the Chromium pages (on the first viewer)."""
    common = [
        "--seconds",
        str(args.seconds),
        "--users-json",
        json.dumps(users),
        "--address",
        address,
        "--arena",
        arena,
    ]
    children: list[Child] = []
    per_viewer = [len(range(i, args.sessions, len(ws_urls))) for i in range(len(ws_urls))]
    slow_left = args.slow
    for i, (url, sessions) in enumerate(zip(ws_urls, per_viewer, strict=True)):
        slow = min(slow_left, sessions)
        slow_left -= slow
        children.append(
            Child(
                f"headless-{i}" if len(ws_urls) > 1 else "headless",
                [
                    "--as-clients",
                    url,
                    "--sessions",
                    str(sessions),
                    "--slow",
                    str(slow),
                    "--slow-every",
                    str(args.slow_every),
                    *common,
                ],
            )
        )
    if args.browsers:
        children.append(
            Child(
                "chromium", ["--as-browsers", http_url, "--browsers", str(args.browsers), *common]
            )
        )
    return children


def _merge(results: list[dict[str, Any]]) -> dict[str, Any]:
    """The headless children's results as one class (means weighted by sessions)."""

    def merged(key: str) -> dict[str, float]:
        parts = [(r[key], r["sessions"] if key != "slow_frames" else r["slow"]) for r in results]
        parts = [(st, n) for st, n in parts if n]
        if not parts:
            return _stats([])
        total = sum(n for _, n in parts)
        return {
            "min": min(st["min"] for st, _ in parts),
            "mean": sum(st["mean"] * n for st, n in parts) / total,
            "max": max(st["max"] for st, _ in parts),
        }

    return {
        "frames": merged("frames"),
        "slow_frames": merged("slow_frames"),
        "mb": merged("mb"),
        "client_cpu": sum(r["client_cpu"] for r in results),
        "errors": [e for r in results for e in r["errors"]][:5],
        "failed": [f for r in results for f in r.get("failed", [])],
        "retried": [f for r in results for f in r.get("retried", [])],
    }


def _thread_cpu() -> dict[str, float]:
    """CPU seconds so far of each of this process's threads, by thread name."""
    import psutil

    names = {t.native_id: t.name for t in threading.enumerate()}
    out: dict[str, float] = {}
    for t in psutil.Process().threads():
        name = names.get(t.id, "other")
        out[name] = out.get(name, 0.0) + t.user_time + t.system_time
    return out


def _cpu_over(seconds: float) -> tuple[float, dict[str, float]]:
    """This process's CPU time over ``seconds`` of wall time, as a share of one core
    (and each thread's share, the busiest first)."""
    c0, t0, th0 = time.process_time(), time.monotonic(), _thread_cpu()
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    th1 = _thread_cpu()
    threads = {n: (v - th0.get(n, 0.0)) / elapsed for n, v in th1.items()}
    top = dict(sorted(threads.items(), key=lambda kv: -kv[1])[:4])
    return (time.process_time() - c0) / elapsed, top


def _print_sessions(
    args: argparse.Namespace, head: dict[str, Any], results: dict[str, dict[str, Any]]
) -> None:
    """What the class received: headless sessions, slow readers, Chromium pages, bytes."""
    f, mb = head["frames"], head["mb"]
    print(
        f"  headless updates/s per session: min {f['min']:.1f} mean {f['mean']:.1f} "
        f"max {f['max']:.1f}"
    )
    if args.slow:
        s = head["slow_frames"]
        print(
            f"  slow readers ({args.slow}, reading every {args.slow_every} s): "
            f"min {s['min']:.1f} mean {s['mean']:.1f} max {s['max']:.1f} updates/s"
        )
    if "chromium" in results:
        cf, cm = results["chromium"]["frames"], results["chromium"]["mb"]
        paint = results["chromium"]["paint_fps"]
        print(
            f"  Chromium updates/s per page: min {cf['min']:.1f} mean {cf['mean']:.1f} "
            f"max {cf['max']:.1f}; {cm['mean']:.3f} MB/s per page; the page painted "
            f"{paint['min']:.1f} to {paint['max']:.1f} animation frames/s"
        )
    print(f"  bytes per session: {mb['mean']:.3f} MB/s (min {mb['min']:.3f}, max {mb['max']:.3f})")


def run_arena(args: argparse.Namespace, robots: int) -> None:
    from tests.conftest import free_port
    from viewers.web.app import WebViewer
    from viewers.web.demo_lab import DemoConnector, DemoLab

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


def _proc_cpu(pids: dict[str, int], seconds: float) -> dict[str, float]:
    """Each named process's CPU over ``seconds`` of wall time, as a share of one core."""
    import psutil

    procs = {name: psutil.Process(pid) for name, pid in pids.items()}
    t0 = time.monotonic()
    c0 = {n: sum(p.cpu_times()[:2]) for n, p in procs.items()}
    time.sleep(seconds)
    elapsed = time.monotonic() - t0
    return {n: (sum(p.cpu_times()[:2]) - c0[n]) / elapsed for n, p in procs.items()}


def run_real(args: argparse.Namespace, robots: int) -> None:
    """The class on a real lab: router, registry and engine as ``wart`` processes, and
    ``--viewers`` viewer processes on the same lab, each serving its share of the class
    (a student's address can name any of them)."""
    from bench.labproc import BenchLab
    from common.keys import AliveKind
    from tests.conftest import free_port

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


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--robots", type=int, nargs="+", default=[35, 1000])
    ap.add_argument("--sessions", type=int, default=100)
    ap.add_argument("--browsers", type=int, default=2, help="real Chromium pages beside them")
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--world-rate", type=float, default=50.0)
    ap.add_argument("--rate", type=float, default=25.0, help="the viewer's pump rate")
    ap.add_argument("--slow", type=int, default=0, help="headless clients that read slowly")
    ap.add_argument("--slow-every", type=float, default=1.0)
    ap.add_argument(
        "--real",
        action="store_true",
        help="a real lab (router, registry, engine with --wander) and --viewers viewer processes",
    )
    ap.add_argument(
        "--viewers", type=int, default=1, help="viewer processes serving the class (with --real)"
    )
    ap.add_argument("--as-clients", metavar="WS_URL", help=argparse.SUPPRESS)
    ap.add_argument("--users-json", help=argparse.SUPPRESS)
    ap.add_argument("--address", default="127.0.0.1", help=argparse.SUPPRESS)
    ap.add_argument("--arena", default=ARENA, help=argparse.SUPPRESS)
    ap.add_argument("--as-browsers", metavar="HTTP_URL", help=argparse.SUPPRESS)
    args = ap.parse_args()
    for name in ("sessions", "browsers", "slow"):
        if getattr(args, name) < 0:
            ap.error(f"--{name} must not be negative")
    if not 0 < args.seconds <= 3600 or not 0 < args.rate <= 60 or args.slow > args.sessions:
        ap.error("--seconds in (0, 3600], --rate in (0, 60], --slow at most --sessions")
    users: list[tuple[str, str]] = (
        [(str(u), str(p)) for u, p in json.loads(args.users_json)] if args.users_json else USERS
    )
    if args.as_clients:
        asyncio.run(
            _clients(
                args.as_clients.split(","),
                args.sessions,
                args.seconds,
                args.slow,
                args.slow_every,
                users,
                args.arena,
            )
        )
        return 0
    if args.as_browsers:
        _browsers(
            args.as_browsers,
            args.browsers,
            args.seconds,
            users,
            args.address,
            args.arena,
        )
        return 0
    if args.viewers < 1 or (args.viewers > 1 and not args.real):
        ap.error("--viewers must be at least 1, and more than 1 needs --real")
    for robots in args.robots:
        if robots < 1:
            ap.error("--robots must be at least 1")
        if args.real:
            run_real(args, robots)
        else:
            run_arena(args, robots)
    return 0


if __name__ == "__main__":
    sys.exit(main())
