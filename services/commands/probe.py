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

import sys
from collections.abc import Sequence

from common import cli, keys
from common.keys import AliveKind
from common.service import close_session, open_session

NOT_ALIVE = 1
NO_ROUTER = 2


def main(argv: Sequence[str] | None = None, prog: str = "wart probe") -> int:
    p = cli.parser(prog, __doc__ or "")
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
    args, options = cli.parse(p, argv)
    assert options is not None
    if not 0.1 <= args.timeout <= 60:
        return cli.fail(f"--timeout is {args.timeout:g}: give 0.1 to 60 seconds")
    try:
        key = keys.alive(options.realm, AliveKind(args.kind), args.ident)
    except ValueError as exc:
        return cli.fail(str(exc))
    try:
        session = open_session(options, wait=args.timeout, quiet=True)
    except ConnectionError as exc:
        if args.liveness:
            print(f"no router answered ({exc}): not this service's fault, alive")
            return 0
        print(f"not ready: {exc}", file=sys.stderr)
        return NO_ROUTER
    try:
        replies = session.liveliness().get(key, timeout=args.timeout)
        found = any(reply.ok is not None for reply in replies)
    finally:
        close_session(session)
    if found:
        print(f"{args.kind} {args.ident} is alive ({key})")
        return 0
    print(f"{args.kind} {args.ident} is not in the lab: no token {key}", file=sys.stderr)
    return NOT_ALIVE
