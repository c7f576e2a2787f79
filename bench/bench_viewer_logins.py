"""A class logging in through one real `wart viewer`: is every "Log in" click answered?

A router, the registry (real argon2id checks; users ana and ben) and one viewer, as
``wart`` processes; ``--sessions`` headless clients (tests/kit/viser_client.py) in this
process connect and log in through the page's own form, ``--at-once`` at a time,
each clicking "Log in" the moment it shows. A client refused with a message tries
once more, as a student would. Printed: how many were let in, refused (and with
which words), or never answered within ``--bound`` seconds; the time from the click
to the answer. No engine: this is the login path alone (issue 22).

    python -m bench.bench_viewer_logins --sessions 100 --at-once 10

To load the machine as a busy class does, start a few ``yes > /dev/null`` beside it.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import time
from collections import Counter

from bench import cli as bench_cli
from bench.labproc import BenchLab
from bench.quantiles import percentile
from common.keys import AliveKind
from tests.kit.procs import free_port
from tests.kit.viser_client import ViserClient

PASSWORD = "class-of-2026"


def _answer(client: ViserClient) -> str:
    if any(n.startswith("Logged in to") for n in client.notifications):
        return "in"
    problem = client.markdown_containing("Could not")
    if problem is not None and problem.props.get("visible", True):
        return str(problem.props.get("_markdown", "")).strip("*")
    return ""


async def _attempt(client: ViserClient, user: str, bound: float) -> tuple[str, float]:
    started = time.monotonic()
    with contextlib.suppress(ConnectionError, TimeoutError):
        await client.log_in(user, PASSWORD, timeout=bound)
    return _answer(client), time.monotonic() - started


async def _class(url: str, sessions: int, at_once: int, bound: float) -> None:
    clients = [ViserClient(url, f"s{i}") for i in range(sessions)]
    gate = asyncio.Semaphore(at_once)
    first: dict[str, tuple[str, float]] = {}
    second: dict[str, tuple[str, float]] = {}
    t0 = time.monotonic()

    async def one(i: int, client: ViserClient) -> None:
        user = ("ana", "ben")[i % 2]
        async with gate:
            await client.connect()
            first[client.name] = await _attempt(client, user, bound)
            if first[client.name][0] not in ("in", ""):
                second[client.name] = await _attempt(client, user, bound)

    try:
        await asyncio.gather(*(one(i, c) for i, c in enumerate(clients)))
    finally:
        await asyncio.gather(*(c.close() for c in clients))
    took = time.monotonic() - t0
    answered = [t for a, t in first.values() if a]
    refused = Counter(a for a, _ in first.values() if a not in ("in", ""))
    never = sorted(n for n, (a, _) in first.items() if not a)
    print(f"RESULTS {sessions} logins, {at_once} at a time, all done after {took:.1f} s")
    print(f"  in at the first try: {sum(a == 'in' for a, _ in first.values())}")
    for text, count in refused.most_common():
        print(f"  refused ({count}): {text}")
    print(f"  never answered within {bound:.0f} s: {len(never)} {never[:5]}")
    print(
        f"  click to answer: p50 {percentile(answered, 0.5):.1f} s, "
        f"p90 {percentile(answered, 0.9):.1f} s, "
        f"max {max(answered, default=float('nan')):.1f} s"
    )
    if second:
        again = Counter(a or "never answered" for a, _ in second.values())
        print(f"  second tries: {dict(again)}")


def main() -> int:
    ap = bench_cli.parser("bench_viewer_logins", __doc__)
    ap.add_argument("--sessions", type=int, default=100)
    ap.add_argument("--at-once", type=int, default=10, help="logins under way at a time")
    ap.add_argument("--bound", type=float, default=120.0, help="seconds a click may wait")
    args = ap.parse_args()
    if not 0 < args.sessions <= 1000 or not args.at_once > 0 or not args.bound > 0:
        ap.error("--sessions 1..1000, --at-once and --bound positive")
    print(f"load average before {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs", flush=True)
    lab = BenchLab(["ana", "ben"], PASSWORD)
    try:
        lab.start()
        port = free_port()
        viewer = ["viewer", "--http-port", str(port), "--id", "web0"]
        lab.spawn(
            [*viewer, "--data-dir", str(lab.tmp / "web0"), *lab.net()], (AliveKind.VIEWER, "web0")
        )
        asyncio.run(_class(f"ws://127.0.0.1:{port}", args.sessions, args.at_once, args.bound))
    finally:
        lab.stop()
    print(f"  load average after {os.getloadavg()[0]:.2f}; logs in {lab.tmp}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
