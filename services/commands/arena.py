"""``wart arena``: start, list and stop simulated arenas on a lab's hosts.

    wart arena list [--lab FILE]
    wart arena new  [--lab FILE] --user NAME --map foraging [--robots 10] [--world NAME] [--on HOST]
    wart arena stop [--lab FILE] --user NAME WORLD
    wart arena estop   [--lab FILE] --user NAME --context CTX [--reason WHY]
    wart arena release [--lab FILE] --user NAME --context CTX
    wart arena settings [--lab FILE] --user NAME --context CTX [--slot SECONDS]
                        [--enable | --disable] [--agent AGENT]
    wart arena takeover ROBOT [--lab FILE] --user NAME --context CTX [--controller FILE]
    wart arena handback ROBOT [--lab FILE] --user NAME --context CTX

``new`` and ``stop`` need the ``host`` permission (instructors and admins);
``estop`` (the emergency stop: every robot of the agent context's arena
stops now, its running controllers end, no slot starts until ``release``;
waiting requests keep their places) needs the context's manage right (its
owner, or ``kick`` there); so does ``settings``, which sets what the page's
arena panel sets: the slot length (``--slot``, 1 to 3600 s, from the next
slot on) and remote control on or off for the whole arena or one robot
(``--enable``/``--disable``, ``--agent``); without a change it shows them; and
so do ``takeover`` (a student's running controller paused, the robot held or
driven by your controller until Ctrl-C; see services/commands/arena_takeover.py)
and ``handback``;
the password comes from --password-file, WART_PASSWORD or a prompt. Without
--on, the host is chosen by load: among hosts that accept an arena now, the
one with the fewest arenas, then the lowest CPU. With --lab the tool joins a
multi-host lab over mutual TLS with a client certificate (--cert, default
"student"); without it, the lab of the network flags (``wart up``'s, whose
one host is "local"; --registry-key or WART_REGISTRY_KEY).
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import zenoh

from common import cli, keys
from common.client.agent_client import AgentClient
from common.client.host_client import (
    HostError,
    choose_host,
    host_arena,
    host_loads,
    stop_hosted,
)
from common.client.lab_client import LabClient
from common.lab_errors import LabError
from common.messages.host import ArenaInfo, HostLoad
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from services.commands.arena_takeover import add_takeover_parsers, run_takeover
from services.commands.control import interrupt_event
from services.commands.terminal import password_from
from services.lab.labfile import LabFileError, load
from services.lab.plan import read_registry_key
from services.lab.zsecurity import client_options

ArenaError = HostError  # the name this module's callers know
__all__ = ["ArenaError", "choose_host", "format_loads", "host_loads", "new_arena", "stop_arena"]


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
    return host_arena(client, world, map_name, robots, host=host, seed=seed, timeout=timeout)


def stop_arena(client: LabClient, world: str, timeout: float = 30.0) -> str:
    return stop_hosted(client, world, "arena", timeout=timeout)


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
        for r in h.rooms:
            lines.append(f"    room {r.name:<15} {r.title[:30]:<30} {r.state:<10} owner {r.owner}")
    return "\n".join(lines)


def add_lab_arguments(p: argparse.ArgumentParser) -> None:
    """--lab and --cert (a multi-host lab); the network flags reach a ``wart up`` lab."""
    p.add_argument("--lab", type=Path, help="a multi-host lab file (default: the network flags)")
    p.add_argument("--cert", default="student", help="client certificate name (PKI/clients/)")


def lab_session(
    args: argparse.Namespace, options: NetworkOptions
) -> tuple[zenoh.Session, str, str]:
    """The Zenoh session, realm and registry key of the lab the tool talks to."""
    if args.lab is not None:
        lab = load(args.lab)
        registry_key = read_registry_key(lab)
        tls = client_options(
            lab, args.cert, connect=tuple(args.connect or ()), registry_key=registry_key
        )
        return open_session(tls, wait=10.0), lab.realm, registry_key
    if not options.registry_key:
        raise HostError(
            "--registry-key (or WART_REGISTRY_KEY) is required: the key wart up printed"
        )
    return open_session(options, wait=10.0), options.realm, options.registry_key


@contextmanager
def lab_login(args: argparse.Namespace, options: NetworkOptions) -> Iterator[LabClient]:
    """A client of the lab logged in as --user; the session is closed after."""
    session, realm, registry_key = lab_session(args, options)
    try:
        with LabClient(session, realm, registry_key, presence=False) as client:
            client.login(args.user, password_from(args))
            yield client
    finally:
        close_session(session)


def run_lab_command(
    p: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    run: Callable[[argparse.Namespace, NetworkOptions], int],
) -> int:
    """Parse the command line and ``run`` it; what the lab or the lab file refuses exits 1."""
    args, options = cli.parse_networked(p, argv)
    try:
        return run(args, options)
    except (LabFileError, LabError, ValueError, OSError) as exc:
        return cli.fail(str(exc), 1)


def _password(args: argparse.Namespace) -> str:

    return password_from(args)


def main(argv: Sequence[str] | None = None, prog: str = "wart arena") -> int:
    p = cli.parser(prog, __doc__ or "")
    add_lab_arguments(p)
    sub = p.add_subparsers(dest="verb", required=True)
    sub.add_parser("list", help="hosts, their load, their arenas and rooms")
    s_new = sub.add_parser("new", help="start an arena on a host chosen by load")
    s_new.add_argument("--map", required=True, help="a map name (maps/NAME.json)")
    s_new.add_argument("--robots", type=int, help="this many Khepera instead of the map's robots")
    s_new.add_argument("--world", help="the new world's name (default MAP-xxxx)")
    s_new.add_argument("--on", dest="host", help="this host instead of the least busy")
    s_new.add_argument("--seed", type=int, default=1)
    s_stop = sub.add_parser("stop", help="stop an arena")
    s_stop.add_argument("world")
    s_estop = sub.add_parser(
        "estop", help="emergency stop: every robot of an arena stops and stays stopped"
    )
    s_estop.add_argument("--reason", default="", help="told to every student whose run ends")
    s_release = sub.add_parser("release", help="release an arena's emergency stop")
    s_settings = sub.add_parser(
        "settings", help="show or set an arena's slot length and who may control its robots"
    )
    s_settings.add_argument("--slot", type=float, help="slot length in seconds (1 to 3600)")
    on_off = s_settings.add_mutually_exclusive_group()
    on_off.add_argument("--enable", action="store_true", help="let students queue (again)")
    on_off.add_argument("--disable", action="store_true", help="queue nothing new; runs end")
    s_settings.add_argument("--agent", help="--enable/--disable this robot only")
    takeover = add_takeover_parsers(sub)
    for s in (s_estop, s_release, s_settings, *takeover):
        s.add_argument("--context", required=True, help="the arena's agent context, e.g. arena")
    for s in (s_new, s_stop, s_estop, s_release, s_settings, *takeover):
        s.add_argument("--user", required=True)
        s.add_argument("--password-file", help="read the password from this file")
    return run_lab_command(p, argv, _run)


def _run(args: argparse.Namespace, options: NetworkOptions) -> int:
    if getattr(args, "robots", None) is not None and not 1 <= args.robots <= 1000:
        raise HostError("--robots must be between 1 and 1000")
    if getattr(args, "context", None) is not None:
        keys.check_ident("context", args.context)
    if len(getattr(args, "reason", "")) > 200:
        raise HostError("--reason: at most 200 characters")
    if args.verb == "settings":
        _check_settings(args)
    # Ctrl-C ends a take-over cleanly: the robot is handed back.
    stop = interrupt_event() if args.verb == "takeover" else threading.Event()
    session, realm, registry_key = lab_session(args, options)
    try:
        if args.verb == "list":
            print(format_loads(host_loads(session, realm)))
            return 0
        with LabClient(session, realm, registry_key, presence=False) as client:
            client.login(args.user, _password(args))
            if args.verb == "settings":
                print(_settings(AgentClient(client, args.context), args))
            elif args.verb in ("estop", "release"):
                agents = AgentClient(client, args.context)
                reason = getattr(args, "reason", "")
                print(agents.emergency_stop(reason, release=args.verb == "release"))
            elif args.verb in ("takeover", "handback"):
                return run_takeover(AgentClient(client, args.context).join(), args, stop)
            elif args.verb == "new":
                arena = host_arena(
                    client, args.world, args.map, args.robots, host=args.host, seed=args.seed
                )
                print(f"arena {arena.world} ({arena.map}) is running on {arena.host}")
            else:
                print(stop_hosted(client, args.world, "arena"))
        return 0
    finally:
        close_session(session)


def _check_settings(args: argparse.Namespace) -> None:
    slot = args.slot
    if slot is not None and not (math.isfinite(slot) and 1.0 <= slot <= 3600.0):
        raise HostError(f"--slot must be between 1 and 3600 seconds, not {slot:g}")
    if args.agent is not None:
        keys.check_ident("agent", args.agent)
        if not (args.enable or args.disable):
            raise HostError("--agent says which robot --enable or --disable applies to")


def _settings(agents: AgentClient, args: argparse.Namespace) -> str:
    """Change what was asked (the context's own words back), then show the settings."""
    said = []
    if args.slot is not None:
        said.append(agents.settings(slot_seconds=args.slot))
    if args.enable or args.disable:
        said.append(agents.settings(enabled=bool(args.enable), agent=args.agent))
    state = agents.state()
    off = [q.agent for q in state.agents if not q.enabled]
    lines = [*said, f"arena {args.context} (world {state.world}):"]
    lines.append(f"  slot length   {state.slot_seconds:g} s")
    lines.append(f"  remote control {'on' if state.enabled else 'off'} for the arena")
    lines.append(f"  robots off    {', '.join(off) if off else 'none'}")
    if state.estop:
        lines.append(f"  {state.estop}")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
