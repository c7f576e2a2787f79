"""Web viewer benchmark: N browsers watching a 1,000-robot world fed at 50 Hz.

Starts a WebViewer on an in-memory lab (fake world at --world-rate Hz), opens
--browsers headless Chromium pages (Debian's chromium-headless-shell via
Playwright, tests/kit/pages.py), logs each one in and joins the arena, then for --seconds counts:

- in each page: websocket messages received and bytes, via a WebSocket
  wrapper injected before viser's code runs (each paced frame is one atomic
  batch, so messages per second is an upper bound on frames per second);
- on the server: frames applied per view (``WorldView.frames_applied``);
- the viewer's CPU: this process's CPU time minus Chromium's (Chromium runs
  in child processes, measured separately), via psutil.

    .venv/bin/python -m bench.bench_viewer --browsers 10 --robots 1000
    .venv/bin/python -m bench.bench_viewer --real --browsers 4   # real engine, maps/swarm.json

With ``--real`` the lab is real processes (router, registry, lobby room and
a Sim2D engine on maps/swarm.json: 1,000 Khepera wandering with ``--wander``,
since viser sends nothing for robots that stand still) and the viewer runs over
:class:`~viewers.web.live.LiveConnector`, as in tests/browser/test_real_lab.py;
the process CPU then excludes the world (the engine is its own process).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING

import psutil
from playwright.sync_api import sync_playwright

from bench import cli as bench_cli
from tests.kit.pages import ViserPage, launch_chromium
from tests.kit.procs import free_port
from tests.kit.reallab import PASSWORD, WORLD, real_lab
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoConnector, DemoLab

if TYPE_CHECKING:  # playwright is imported where the bench runs it
    from playwright.sync_api import ViewportSize

BENCH_VIEWPORT: ViewportSize = {"width": 960, "height": 600}


class WsCounter:
    """Counts websocket frames a page receives (Playwright's view of the page's network).

    viser's websocket lives in a Web Worker, out of reach of a script injected in
    the page, so frames are counted through Playwright's websocket events, which
    fire for every frame the browser received.
    """

    def __init__(self) -> None:
        self.messages = 0
        self.bytes = 0
        self._lock = threading.Lock()

    def attach(self, page: object) -> None:
        page.on("websocket", self._on_socket)  # type: ignore[attr-defined]

    def _on_socket(self, ws: object) -> None:
        ws.on("framereceived", self._on_frame)  # type: ignore[attr-defined]

    def _on_frame(self, payload: bytes | str) -> None:
        with self._lock:
            self.messages += 1
            self.bytes += len(payload)

    def read(self) -> dict[str, float]:
        with self._lock:
            return {"messages": self.messages, "bytes": self.bytes}


def main() -> int:
    ap = bench_cli.parser("bench_viewer", __doc__)
    ap.add_argument("--browsers", type=int, default=10)
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--world-rate", type=float, default=50.0)
    ap.add_argument("--rate", type=float, default=25.0, help="the viewer's pump rate")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--real", action="store_true", help="real lab processes, maps/swarm.json")
    args = ap.parse_args()
    if args.real:
        with ExitStack() as stack:
            env = stack.enter_context(real_lab(Path(tempfile.mkdtemp()), "swarm", wander=True))
            users = [(u, PASSWORD) for u in ("alice", "bob", "carol", "ida")]
            return run(args, env.viewer, env.url, env.address.label, WORLD, users, None)
    lab = DemoLab("Bench lab", robots=args.robots, rate=args.world_rate)
    viewer = WebViewer(DemoConnector(("lab", lab)), port=free_port(), rate=args.rate)
    try:
        users = [("ana", "ana-pw"), ("ben", "ben-pw")]
        return run(args, viewer, "127.0.0.1", "lab@127.0.0.1", "arena", users, lab)
    finally:
        viewer.stop()
        lab.close()


def run(
    args: argparse.Namespace,
    viewer: WebViewer,
    address: str,
    tab: str,
    arena: str,
    users: list[tuple[str, str]],
    lab: DemoLab | None,
) -> int:
    me = psutil.Process()
    with sync_playwright() as pw:
        browser = launch_chromium(pw)
        pages: list[ViserPage] = []
        counters: list[WsCounter] = []
        for i in range(args.browsers):
            # Software WebGL shares this machine's cores with the viewer: a small
            # window keeps 10 pages' rendering from starving the server under test.
            context = browser.new_context(viewport=BENCH_VIEWPORT)
            page = context.new_page()
            counter = WsCounter()
            counter.attach(page)
            counters.append(counter)
            page.goto(viewer.url)
            vp = ViserPage(page, f"bench-{i}")
            vp.wait_ready(60_000)
            user, password = users[i % len(users)]
            vp.log_in(address, user, password)
            vp.tab(tab).first.click()
            vp.button(f"Join {arena}").wait_for(timeout=60_000)
            pages.append(vp)
            print(f"browser {i + 1} logged in", flush=True)
        # Join only once every page is up: a page rendering 1,000 robots in
        # software WebGL slows the next page's loading on a small machine.
        for i, vp in enumerate(pages):
            vp.click(f"Join {arena}", timeout=60_000)
            print(f"browser {i + 1} watches the arena", flush=True)
        views = [s.view for s in viewer.sessions.values()]
        deadline = time.monotonic() + 60
        while any(v.frames_applied < 5 for v in views) and time.monotonic() < deadline:
            time.sleep(0.1)
        pages[0].p.wait_for_timeout(2000)  # let every page settle after its join

        def sample() -> tuple[list[dict[str, float]], list[int], float, float]:
            stats = [c.read() for c in counters]
            applied = [v.frames_applied for v in views]
            cpu = me.cpu_times()
            return stats, applied, cpu.user + cpu.system, time.monotonic()

        pump_busy0 = viewer.pump.busy_s
        s0, a0, c0, t0 = sample()
        world0 = views[0].feed.latest() if views[0].feed else None
        # Playwright's sync API delivers events only while it runs: wait inside it.
        pages[0].p.wait_for_timeout(args.seconds * 1000)
        s1, a1, c1, t1 = sample()
        world1 = views[0].feed.latest() if views[0].feed else None
        robots = len(world1.poses) if world1 is not None else 0
        pump_busy = viewer.pump.busy_s - pump_busy0
        elapsed = t1 - t0
        browser.close()

    assert world0 is not None and world1 is not None
    msg_rates = [(b["messages"] - a["messages"]) / elapsed for a, b in zip(s0, s1, strict=True)]
    mb_rates = [(b["bytes"] - a["bytes"]) / elapsed / 1e6 for a, b in zip(s0, s1, strict=True)]
    applied = [(b - a) / elapsed for a, b in zip(a0, a1, strict=True)]
    # Fake frames count 1 per frame; the engine's seq is its tick (50 per simulated s).
    world_rate = (world1.seq - world0.seq) / elapsed
    if lab is None:
        world_rate = (world1.t - world0.t) / elapsed  # simulated s per wall s
    # This process also runs the fake world and Playwright's client; both are
    # counted in, so the viewer's own share is at most this.
    cpu = 100 * (c1 - c0) / elapsed
    print(
        f"browsers {args.browsers}, robots {robots}, "
        + (f"world {world_rate:.1f} frames/s, " if lab else f"world x{world_rate:.2f} realtime, ")
        + f"pump {args.rate:.0f} Hz, {elapsed:.1f} s"
    )
    print(
        f"ws messages/s per browser: min {min(msg_rates):.1f} "
        f"mean {sum(msg_rates) / len(msg_rates):.1f} max {max(msg_rates):.1f}"
    )
    print(f"MB/s per browser: mean {sum(mb_rates) / len(mb_rates):.2f}")
    print(f"frames applied/s per view (server): min {min(applied):.1f} max {max(applied):.1f}")
    print(f"pump thread busy: {100 * pump_busy / elapsed:.1f} % of a core")
    what = "fake world + " if lab else ""
    print(f"viewer process CPU (incl. {what}Playwright client): {cpu:.1f} % of a core")
    print(f"machine: {psutil.cpu_count()} CPUs")
    ok = min(msg_rates) >= 20
    print("target >= 20 updates/s to every browser:", "MET" if ok else "NOT MET")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
