"""``wart arena``: start, list and stop simulated arenas on a lab's hosts.

    wart arena list --lab FILE
    wart arena new  --lab FILE --user NAME --map foraging [--robots 10] [--world NAME] [--on HOST]
    wart arena stop --lab FILE --user NAME WORLD

``new`` and ``stop`` need the ``host`` permission (instructors and admins);
the password comes from --password-file, WART_PASSWORD or a prompt. Without
--on, the host is chosen by load: among hosts that accept an arena now, the
one with the fewest arenas, then the lowest CPU. The tool joins the lab over
mutual TLS with a client certificate (--cert, default "student").
"""

from __future__ import annotations

import argparse
import sys
import uuid
from collections.abc import Sequence
from pathlib import Path

import zenoh

from common import cli, keys
from common.client import LabClient, LabError, _raise_for
from common.labfile import LabFile, LabFileError, load
from common.messages import ErrorReply, MessageError, OkReply, decode, encode
from common.messages.host import ArenaInfo, ArenaReply, HostLoad, LoadRequest, SpawnArena, StopArena
from common.service import close_session, open_session
from common.zsecurity import client_options


class ArenaError(Exception):
    """Why an arena request could not be carried out, in words."""


def host_loads(session: zenoh.Session, realm: str, timeout: float = 3.0) -> list[HostLoad]:
    """Every live host's current load (each host answers on its load key)."""
    loads: dict[str, HostLoad] = {}
    replies = session.get(
        keys.host_load_all(realm),
        payload=encode(LoadRequest()),
        timeout=timeout,
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
    )
    for reply in replies:
        if reply.ok is None:
            continue
        try:
            load_ = decode(reply.ok.payload, HostLoad)
        except MessageError:
            continue
        loads[load_.host] = load_
    return sorted(loads.values(), key=lambda h: h.host)


def choose_host(loads: Sequence[HostLoad], wanted: str | None = None) -> HostLoad:
    """The host an arena goes to: ``wanted`` if given, else the least busy that accepts."""
    if wanted is not None:
        for load_ in loads:
            if load_.host == wanted:
                if not load_.accepting:
                    raise ArenaError(f"host {wanted} takes no arena now: {load_.reason}")
                return load_
        seen = ", ".join(h.host for h in loads) or "none"
        raise ArenaError(f"host {wanted} did not answer (hosts that did: {seen}); is it running?")
    ready = [h for h in loads if h.accepting]
    if not ready:
        if not loads:
            raise ArenaError("no host answered: is `wart host` running on the lab's machines?")
        why = "; ".join(f"{h.host}: {h.reason}" for h in loads)
        raise ArenaError(f"no host takes an arena now ({why})")
    return min(ready, key=lambda h: (len(h.arenas) / max(1, h.max_arenas), h.cpu_percent, h.host))


def _ask(client: LabClient, key: str, message: SpawnArena | StopArena, timeout: float) -> object:
    if client.session is None:
        raise ArenaError("log in first")
    payload = client.session.seal(key, message)
    replies = [r for r in client.z.get(key, payload=payload, timeout=timeout) if r.ok is not None]
    if not replies:
        raise ArenaError(f"no answer on {key}: the host went away or the network dropped it")
    reply = decode(replies[0].ok.payload, (ArenaReply, OkReply, ErrorReply))
    if isinstance(reply, ErrorReply):
        _raise_for(reply, "the host")
    return reply


def new_arena(
    client: LabClient,
    *,
    map_name: str,
    robots: int | None,
    world: str | None,
    host: str | None,
    seed: int = 1,
    timeout: float = 90.0,
) -> ArenaInfo:
    loads = host_loads(client.z, client.realm)
    target = choose_host(loads, host)
    name = world or f"{map_name}-{uuid.uuid4().hex[:4]}"
    keys.check_ident("world", name)
    reply = _ask(
        client,
        keys.host_spawn(client.realm, target.host),
        SpawnArena(world=name, map=map_name, robots=robots, seed=seed),
        timeout,
    )
    assert isinstance(reply, ArenaReply)
    return reply.arena


def stop_arena(client: LabClient, world: str, timeout: float = 30.0) -> str:
    for load_ in host_loads(client.z, client.realm):
        if any(a.world == world for a in load_.arenas):
            reply = _ask(
                client, keys.host_spawn(client.realm, load_.host), StopArena(world=world), timeout
            )
            assert isinstance(reply, OkReply)
            return reply.detail
    raise ArenaError(f"no host runs an arena named {world}")


def format_loads(loads: Sequence[HostLoad]) -> str:
    if not loads:
        return "no host answered"
    lines = []
    for h in loads:
        state = "accepting" if h.accepting else f"full: {h.reason}"
        lines.append(
            f"{h.host}: CPU {h.cpu_percent:.0f} % of {h.cpus}, "
            f"{h.mem_available_mb:.0f}/{h.mem_total_mb:.0f} MB free, "
            f"{len(h.arenas)}/{h.max_arenas} arenas, {state}"
        )
        for a in h.arenas:
            lines.append(
                f"    {a.world:<20} {a.map:<12} robots {a.robots:<4} {a.state:<10} "
                f"owner {a.owner:<10} {a.rss_mb:.0f} MB  CPU {a.cpu_percent:.0f} %"
            )
    return "\n".join(lines)


def _password(args: argparse.Namespace) -> str:
    from services.chat import password_from

    return password_from(args)


def main(argv: Sequence[str] | None = None, prog: str = "wart arena") -> int:
    p = cli.parser(prog, __doc__ or "", network=False)
    p.add_argument("--lab", type=Path, required=True, help="the lab file")
    p.add_argument("--cert", default="student", help="client certificate name (PKI/clients/)")
    p.add_argument("--connect", action="append", help="a router to join (default: any host's)")
    sub = p.add_subparsers(dest="verb", required=True)
    sub.add_parser("list", help="hosts, their load and their arenas")
    s_new = sub.add_parser("new", help="start an arena on a host chosen by load")
    s_new.add_argument("--map", required=True, help="a map name (maps/NAME.json)")
    s_new.add_argument("--robots", type=int, help="this many Khepera instead of the map's robots")
    s_new.add_argument("--world", help="the new world's name (default MAP-xxxx)")
    s_new.add_argument("--on", dest="host", help="this host instead of the least busy")
    s_new.add_argument("--seed", type=int, default=1)
    s_stop = sub.add_parser("stop", help="stop an arena")
    s_stop.add_argument("world")
    for s in (s_new, s_stop):
        s.add_argument("--user", required=True)
        s.add_argument("--password-file", help="read the password from this file")
    args, _ = cli.parse(p, argv)
    try:
        lab = load(args.lab)
        return _run(args, lab)
    except (LabFileError, ArenaError, LabError, ValueError, OSError) as exc:
        return cli.fail(str(exc), 1)


def _run(args: argparse.Namespace, lab: LabFile) -> int:
    from services.hostplan import read_registry_key

    if getattr(args, "robots", None) is not None and not 1 <= args.robots <= 1000:
        raise ArenaError("--robots must be between 1 and 1000")
    registry_key = read_registry_key(lab)
    options = client_options(
        lab, args.cert, connect=tuple(args.connect or ()), registry_key=registry_key
    )
    session = open_session(options, wait=10.0)
    try:
        if args.verb == "list":
            print(format_loads(host_loads(session, lab.realm)))
            return 0
        with LabClient(session, lab.realm, registry_key, presence=False) as client:
            client.login(args.user, _password(args))
            if args.verb == "new":
                arena = new_arena(
                    client,
                    map_name=args.map,
                    robots=args.robots,
                    world=args.world,
                    host=args.host,
                    seed=args.seed,
                )
                print(f"arena {arena.world} ({arena.map}) is running on {arena.host}")
            else:
                print(stop_arena(client, args.world))
        return 0
    finally:
        close_session(session)


if __name__ == "__main__":
    sys.exit(main())
