"""Web viewer benchmark: 100 sessions on one arena (issue 22).

This process runs one WebViewer on the in-memory lab (an arena of --robots
robots whose frames come at --world-rate Hz) and nothing else, so its CPU
time is the viewer's (plus the fake world's thread: measured alone first,
with no session, and subtracted). Two child processes stand for the class:

- ``--as-clients``: --sessions headless websocket clients speaking viser's
  protocol (tests/kit/viser_client.py): each connects, logs in through the GUI
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

    .venv/bin/python -m bench.bench_viewer_sessions --robots 35 1000
    .venv/bin/python -m bench.bench_viewer_sessions --robots 10000 --sessions 10

With --slow K, K of the headless clients read their socket only every
--slow-every seconds (a saturated link, a frozen tab): they should get fewer
frames and the others as many as without them.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from pathlib import Path

from bench import cli as bench_cli
from bench.viewer_class import ARENA, USERS
from bench.viewer_clients import _browsers, _clients
from bench.viewer_runs import run_arena, run_real

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = bench_cli.parser("bench_viewer_sessions", __doc__)
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
