"""A survey of a realm as any client sees it: routers, live services, host loads, findings.

Shared by ``wart doctor`` (with or without a lab file) and the web viewer's
network page for admins, so both say the same things in the same words. It
reads only what Zenoh offers every client: the routers' admin space (which
access control may hide), liveliness tokens and the hosts' load reports.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common import keys
from common.ask import admin_space, alive_keys
from common.client.host_client import host_loads
from common.keys import AliveKind
from common.messages import HostLoad


@dataclass
class RouterView:
    name: str
    zid: str
    rtt_ms: float
    peers: list[str]  # router names it has a link to
    clients: int


def routers(session: zenoh.Session, timeout: float = 3.0) -> list[tuple[dict[str, Any], float]]:
    """The admin view of every router reachable from this session, with each one's RTT."""
    found = admin_space(session, keys.routers_admin_all(), what="routers", timeout=timeout)
    out = []
    for info in found:
        zid = str(info.get("zid", ""))
        started = time.monotonic()
        answered = bool(
            admin_space(session, keys.router_admin(zid), what=f"router {zid}", timeout=timeout)
        )
        rtt = (time.monotonic() - started) * 1000 if answered else float("nan")
        out.append((info, rtt))
    return out


def router_views(raw: list[tuple[dict[str, Any], float]]) -> list[RouterView]:
    names = {}
    for info, _ in raw:
        meta = info.get("metadata") or {}
        names[str(info.get("zid"))] = str(meta.get("name") or str(info.get("zid"))[:8])
    views = []
    for info, rtt in raw:
        sessions = info.get("sessions") or []
        peers = sorted(
            names.get(str(s.get("peer")), str(s.get("peer"))[:8])
            for s in sessions
            if s.get("whatami") == "router"
        )
        clients = sum(1 for s in sessions if s.get("whatami") == "client")
        views.append(
            RouterView(names[str(info.get("zid"))], str(info.get("zid")), rtt, peers, clients)
        )
    return sorted(views, key=lambda v: v.name)


def alive_by_kind(session: zenoh.Session, realm: str, timeout: float = 3.0) -> dict[str, list[str]]:
    """Every live token of the realm, grouped by kind (``{"world": ["arena1"], ...}``)."""
    alive: dict[str, list[str]] = {}
    for key in alive_keys(session, keys.alive_all(realm), what="live services", timeout=timeout):
        parsed = keys.parse_alive(realm, key)
        if parsed is not None:
            alive.setdefault(parsed[0].value, []).append(parsed[1])
    return {kind: sorted(set(ids)) for kind, ids in sorted(alive.items())}


@dataclass
class Survey:
    realm: str
    routers: list[RouterView]
    alive: dict[str, list[str]]
    hosts: list[HostLoad]
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    took_ms: float = 0.0

    def lines(self) -> list[str]:
        """The survey as plain text lines (the doctor prints them; the page renders them)."""
        out = [f"realm {self.realm} (surveyed in {self.took_ms:.0f} ms)"]
        out.append("routers:")
        for r in self.routers:
            rtt = "no answer" if math.isnan(r.rtt_ms) else f"{r.rtt_ms:.1f} ms"
            links = ", ".join(r.peers) or "no other router"
            out.append(f"  {r.name} ({r.zid[:8]}): {rtt}; links to {links}; {r.clients} clients")
        if not self.routers:
            out.append("  (not visible to this session)")
        out.append("services alive:")
        for kind, ids in self.alive.items():
            out.append(f"  {kind}: {', '.join(ids)}")
        for load in self.hosts:
            arenas = ", ".join(a.world for a in load.arenas) or "none"
            state = "accepting arenas" if load.accepting else f"not accepting: {load.reason}"
            out.append(
                f"host {load.host}: CPU {load.cpu_percent:.0f} % of {load.cpus}, "
                f"{load.mem_available_mb:.0f} MB free, arenas {arenas}; {state}"
            )
        for text in self.notes:
            out.append(f"note: {text}")
        for text in self.problems:
            out.append(f"PROBLEM: {text}")
        return out


def survey(session: zenoh.Session, realm: str, timeout: float = 3.0) -> Survey:
    """Look at the realm from ``session`` and say, in words, what looks wrong."""
    started = time.monotonic()
    views = router_views(routers(session, timeout))
    alive = alive_by_kind(session, realm, timeout)
    hosts = host_loads(session, realm, timeout)
    result = Survey(realm, views, alive, hosts)
    if not views:
        result.notes.append(
            "the routers' admin space did not answer this session: routers without "
            "adminspace, or access control reserving it to admins"
        )
    for view in views:
        if math.isnan(view.rtt_ms):
            result.problems.append(f"router {view.name} was seen but did not answer a query")
    if not alive.get(AliveKind.REGISTRY.value):
        result.problems.append(
            "no registry is alive: nobody can log in (is `wart registry` running? see its log)"
        )
    if alive.get(AliveKind.CONTEXT.value) and not alive.get(AliveKind.WORLD.value):
        result.notes.append("contexts are alive but no world (engine or bridge) is")
    if alive.get(AliveKind.WORLD.value) and not alive.get(AliveKind.RUNNER.value):
        result.notes.append("no runner is alive: uploaded controllers cannot run")
    for load in hosts:
        if not load.accepting and load.reason:
            result.notes.append(f"host {load.host} takes no new arena: {load.reason}")
    result.took_ms = (time.monotonic() - started) * 1000
    return result
