"""bench_viewer_sessions' class, in its child processes: headless sessions and Chromium pages.

``_clients`` runs in ``--as-clients``: headless websocket clients speaking
viser's protocol (tests/kit/viser_client.py), each logging in, joining the arena
and counting the frames and bytes it receives; ``_browsers`` in
``--as-browsers``: real Chromium pages (Playwright) doing the same. Both say
READY, wait for GO, measure, and print one RESULT line of JSON.
"""

from __future__ import annotations

import asyncio
import json
import sys
import time

from common.client.lab_address import parse_address
from tests.kit.viser_client import ViserClient


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
    # playwright is optional: only the browser clients need it, and these modules
    # import it at their top (the token clients' process runs without it).
    from playwright.sync_api import sync_playwright

    from bench.bench_viewer import BENCH_VIEWPORT, WsCounter
    from tests.kit.pages import ViserPage, launch_chromium  # imports playwright too

    with sync_playwright() as pw:
        browser = launch_chromium(pw)
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
