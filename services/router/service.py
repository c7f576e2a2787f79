"""``wart router``: a Zenoh router in a Python process (no zenohd binary needed).

Every host of a lab runs one; services and browsers' gateways connect to it as
clients, and routers of several hosts mesh with ``--connect``. It listens on
127.0.0.1 by default; a lab host that others must reach listens on all
interfaces: ``wart router --listen tcp/0.0.0.0:7447``.
"""

from __future__ import annotations

import socket

from common import keys
from common.ask import admin_space
from common.keys import AliveKind, is_ident
from common.service import Service


class Router(Service):
    """The router's own presence; the routing is Zenoh's, in the same session."""

    kind = AliveKind.ROUTER

    def locators(self) -> list[str]:
        """The endpoints this router actually listens on (port 0 resolved)."""
        zid = str(self.session.zid())
        for info in admin_space(self.session, keys.router_admin(zid), what="router", timeout=2.0):
            return [str(loc) for loc in info.get("locators", [])]
        return []


def default_name() -> str:
    name = socket.gethostname().split(".")[0]
    return name if is_ident(name) else "router"
