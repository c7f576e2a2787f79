"""``wart router``: the command line; what the service does is service.py's docstring."""

from __future__ import annotations

from collections.abc import Sequence

import zenoh

from common import cli
from common.service import run_service
from common.zconfig import DEFAULT_PORT
from services.router import service
from services.router.service import Router, default_name


def main(argv: Sequence[str] | None = None, prog: str = "wart router") -> int:
    p = cli.parser(prog, service.__doc__ or "", default_mode="router")
    p.add_argument("--name", default=default_name(), help="this router's name (default: host name)")
    args, options = cli.parse_networked(p, argv)
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
