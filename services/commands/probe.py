"""``wart probe KIND ID``: is this service in the lab? For Kubernetes' probes.

    wart probe world arena1                 # readiness: the engine's token is in the lab
    wart probe world arena1 --liveness      # liveness: its token is gone while the router works

A service is in the lab while its liveliness token ``wart/<realm>/alive/KIND/ID``
is (the directory, the supervisors and ``wart doctor`` read the same tokens):
the token is declared once the service serves, and goes when its process or
its link to the router does. The probe asks the router for that one token
with the pod's own network settings (WART_CONNECT, WART_ZENOH_CONFIG...), and

- exits 0 when the token is there;
- exits 1 when it is not, saying which token it looked for;
- exits 2 when no router answered: unready, but with ``--liveness`` this is 0,
  since a router being replaced is no reason to restart every pod that uses it
  (the services reconnect by themselves).

KIND is one of the token kinds (world, context, registry, runner, viewer,
grader, camera, lti, router, host).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

import zenoh

# Not common.cli nor common.service: the probe runs every few seconds in every pod, and
# they import the messages and numpy (0.4 s of CPU a probe, measured; 0.05 s without).
from common.keys import AliveKind, alive
from common.zconfig import ConfigError, add_network_arguments, options_from_args, zenoh_config

NOT_ALIVE = 1
NO_ROUTER = 2


def _open(config: zenoh.Config, timeout: float) -> zenoh.Session | None:
    """A session to the router, retried until ``timeout``; None if none answered."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return zenoh.open(config)
        except Exception:  # zenoh raises ZError for an unreachable router
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.2)


def main(argv: Sequence[str] | None = None, prog: str = "wart probe") -> int:
    p = argparse.ArgumentParser(
        prog=prog, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("kind", choices=[k.value for k in AliveKind if k != AliveKind.USER])
    p.add_argument("ident", metavar="ID", help="the service's name (a world, a room, ...)")
    p.add_argument(
        "--liveness",
        action="store_true",
        help="pass when no router answers (only a token gone from a working router fails)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=3.0,
        help="seconds to wait for the router and for its answer (default 3)",
    )
    add_network_arguments(p)
    args = p.parse_args(argv)
    try:
        options = options_from_args(args)
    except ConfigError as exc:
        p.error(str(exc))
    if not 0.1 <= args.timeout <= 60:
        p.error(f"--timeout is {args.timeout:g}: give 0.1 to 60 seconds")
    try:
        key = alive(options.realm, AliveKind(args.kind), args.ident)
    except ValueError as exc:
        p.error(str(exc))
    session = _open(zenoh_config(options), args.timeout)
    where = ", ".join(options.effective_connect)
    if session is None:
        if args.liveness:
            print(f"no router answered at {where}: not this service's fault, alive")
            return 0
        print(f"not ready: no Zenoh router reachable at {where}", file=sys.stderr)
        return NO_ROUTER
    try:
        replies = session.liveliness().get(key, timeout=args.timeout)
        found = any(reply.ok is not None for reply in replies)
    finally:
        session.close()
    if found:
        print(f"{args.kind} {args.ident} is alive ({key})")
        return 0
    print(f"{args.kind} {args.ident} is not in the lab: no token {key}", file=sys.stderr)
    return NOT_ALIVE
