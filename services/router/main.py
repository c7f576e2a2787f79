"""``wart router``: a Zenoh router in a Python process (no zenohd binary needed).

Every host of a lab runs one; services and browsers' gateways connect to it as
clients, and routers of several hosts mesh with ``--connect``. It listens on
127.0.0.1 by default; a lab host that others must reach listens on all
interfaces: ``wart router --listen tcp/0.0.0.0:7447``.
"""

from __future__ import annotations

from collections.abc import Sequence

import zenoh

from common import cli
from common.service import run_service
from common.zconfig import DEFAULT_PORT
from services.router.service import Router, default_name


def main(argv: Sequence[str] | None = None, prog: str = "wart router") -> int:
    p = cli.parser(prog, __doc__ or "", default_mode="router")
    p.add_argument("--name", default=default_name(), help="this router's name (default: host name)")
    args, options = cli.parse(p, argv)
    assert options is not None
    if options.mode != "router":
        p.error("a router runs in router mode; drop --mode")
    if not options.listen:
        options = options.with_(listen=(f"tcp/127.0.0.1:{DEFAULT_PORT}",))
    # The name in the metadata is what `wart doctor` and the admin page show.
    options = options.with_(
        extra={"adminspace/enabled": True, "metadata": {"name": args.name, "realm": options.realm}}
    )

    def build(session: zenoh.Session) -> Router:
        router = Router(session, options.realm, args.name)
        for locator in router.locators() or list(options.listen):
            router.log.info("listening on %s", locator)
        for endpoint in options.connect:
            router.log.info("meshing with the router at %s", endpoint)
        return router

    return run_service(f"router {args.name}", options, build, wait_for_router=10.0)
