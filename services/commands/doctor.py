"""``wart doctor [--lab FILE]``: is the lab healthy, and if not, what is wrong, in words.

Without ``--lab`` (a one-machine ``wart up`` lab, or any lab seen as a plain
client with the usual --connect/--realm flags), it surveys what any client
sees: the routers' admin space, every live service and the hosts' loads.
With a lab file:

Checks, for each host of the lab file: that its router's port answers (TCP),
that a mutual-TLS Zenoh session opens to it, the round-trip time of a query
to its admin space, its links to the other routers, the services the lab file
gives it (their liveliness tokens) and its load report. Then lists every live
token of the realm and the arenas. Uses an operator's client certificate
(``--cert admin``): the routers let only admins read their admin space.
Exit code 0 when nothing is wrong, 1 otherwise.

Either way it first checks this machine's plugins (entry points
``wart.components``, ``wart.agents``, ``wart.engines``, ``wart.contexts``,
docs/ROBOTS.md): one that fails to import or declares a bad schema is a
problem, with the reason (the lab runs without it). ``--plugins``: only that.
"""

from __future__ import annotations

import argparse
import errno
import socket
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

from common import cli, keys
from common.ask import alive_keys
from common.client.survey import router_views, routers, survey
from common.keys import AliveKind
from common.robots import registry
from common.service import close_session, open_session
from common.zconfig import DEFAULT_PORT, NetworkOptions
from services.commands import up
from services.commands.arena import format_loads, host_loads
from services.lab.labfile import HostEntry, LabFile, LabFileError, load
from services.lab.plan import HostContext, host_plan, host_state_dir, router_spec
from services.lab.supervisor import ChildSpec
from services.lab.wiring import arena_context
from services.lab.zsecurity import client_options


@dataclass
class Report:
    lines: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    def ok(self, text: str) -> None:
        self.lines.append(f"  ✓ {text}")

    def bad(self, text: str) -> None:
        self.lines.append(f"  ✗ {text}")
        self.problems.append(text)

    def info(self, text: str) -> None:
        self.lines.append(f"    {text}")

    def head(self, text: str) -> None:
        self.lines.append(text)


def tcp_check(host: HostEntry, timeout: float = 2.0) -> str | None:
    """None if the router's port accepts a TCP connection, else why not, in words."""
    try:
        with socket.create_connection((host.address, host.port), timeout=timeout):
            return None
    except ConnectionRefusedError:
        return (
            f"no router at {host.endpoint}: connection refused — is `wart host` running on "
            f"{host.name}? is port {host.port} open in its firewall?"
        )
    except TimeoutError:
        return (
            f"no answer from {host.address}:{host.port} within {timeout:.0f} s — is {host.name} "
            f"up and reachable (network link, routing, a firewall dropping port {host.port})?"
        )
    except OSError as exc:
        if exc.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH):
            return f"{host.address} is unreachable from here ({exc.strerror}): check the network"
        return f"cannot reach {host.endpoint}: {exc.strerror or exc}"


def tls_check(lab: LabFile, host: HostEntry, cert: str) -> tuple[zenoh.Session | None, str]:
    """A session to this host's router alone; (None, why) if TLS or Zenoh refuses it."""
    options = client_options(lab, cert, connect=(host.endpoint,))
    started = time.monotonic()
    try:
        session = open_session(options, wait=0.0, quiet=True)
    except ConnectionError as exc:
        return None, (
            f"the port answers but a Zenoh TLS session to {host.endpoint} fails: "
            f"{str(exc).splitlines()[0][:160]} — check that {host.name}'s certificate is signed "
            f"by this lab's CA ({lab.security.pki / 'ca.pem'}) and names {host.address}, and "
            f"that the client certificate '{cert}' is valid"
        )
    return session, f"{(time.monotonic() - started) * 1000:.0f} ms to open"


def planned(specs: list[ChildSpec], host: str, host_token: str) -> list[tuple[str, str]]:
    """(what, liveliness key) of every process a host's supervisor runs, from its plan.

    The plan is the planner's own (services/lab/wiring.py, what ``wart host`` and
    ``wart up`` start), so an engine's named context or a viewer's id is
    expected under the name it really has. The supervisor itself is the host's
    hosting service (its token ``alive/host/HOST``); a process off the network
    (an emulated Khepera) has no token, its bridge stands for it.
    """
    out = [(f"host {host}", host_token)]
    out += [(spec.name, spec.alive_key) for spec in specs if spec.alive_key]
    return out


def lab_file_plan(lab: LabFile, host: HostEntry) -> list[tuple[str, str]]:
    """What ``wart host --lab FILE --name HOST`` runs, with each process's token."""
    ctx = HostContext(lab, host, host_state_dir(lab, host), registry_key="")
    host_token = keys.alive(lab.realm, AliveKind.HOST, host.name)
    return planned([router_spec(ctx), *host_plan(ctx)], host.name, host_token)


def up_plan(options: NetworkOptions) -> list[tuple[str, str]]:
    """What ``wart up`` runs (host ``local``): its own plan, whatever its ports and state."""
    settings = up.settings_from_args(
        argparse.Namespace(state_dir=None, port=DEFAULT_PORT, http_port=8080), options
    )
    # Its router may be another lab's (``wart up --connect``): the survey lists routers.
    host_token = keys.alive(options.realm, AliveKind.HOST, up.HOST_NAME)
    return planned(up.lab_plan(settings), up.HOST_NAME, host_token)


def diagnose(lab: LabFile, cert: str, say: Callable[[str], None] = print) -> Report:

    report = Report()
    sessions: list[zenoh.Session] = []
    try:
        report.head(f"lab '{lab.realm}' ({lab.path}), {len(lab.hosts)} hosts")
        reachable: list[HostEntry] = []
        for host in lab.hosts:
            report.head(f"host {host.name} ({host.endpoint})")
            why = tcp_check(host)
            if why:
                report.bad(why)
                continue
            session, detail = tls_check(lab, host, cert)
            if session is None:
                report.bad(detail)
                continue
            sessions.append(session)
            reachable.append(host)
            report.ok(f"router answers over mutual TLS ({detail})")
        if not sessions:
            report.head("nothing reachable: no further checks")
            return report
        session = sessions[0]
        views = router_views(routers(session))
        report.head("routers and links (admin space)")
        if not views:
            report.bad(
                "no router admin space answered: is this certificate an admin one "
                f"(--cert, one of {', '.join(lab.security.admin_names)})?"
            )
        for view in views:
            report.ok(
                f"router {view.name}: rtt {view.rtt_ms:.1f} ms, links to "
                f"{', '.join(view.peers) or 'no other router'}, {view.clients} clients"
            )
        seen = {v.name for v in views}
        for host in lab.hosts:
            if host.name not in seen and host in reachable:
                report.bad(f"router {host.name} answers TLS but not in the mesh seen from here")
            for other in host.connect:
                mesh_view = next((v for v in views if v.name == host.name), None)
                if mesh_view is not None and other in seen and other not in mesh_view.peers:
                    report.bad(
                        f"router {host.name} has no link to {other} (it should connect to "
                        f"{lab.host(other).endpoint}): check {host.name}'s router log"
                    )
        report.head("services (liveliness)")
        live = set(alive_keys(session, keys.alive_all(lab.realm), what="services", timeout=3.0))
        expected: set[str] = set()
        for host in lab.hosts:
            try:
                plan = lab_file_plan(lab, host)
            except (FileNotFoundError, ValueError) as exc:
                report.bad(f"cannot tell what {host.name} should run: {exc}")
                continue
            for what, key in plan:
                expected.add(key)
                if key in live:
                    report.ok(f"{what} on {host.name} is alive")
                else:
                    report.bad(
                        f"{what} on {host.name} is not alive: look at the log of `wart host` "
                        f"on {host.name} (STATE_DIR/logs/)"
                    )
        for key in sorted(live - expected):
            parsed = keys.parse_alive(lab.realm, key)
            if parsed:
                report.info(f"also alive: {parsed[0].value} {parsed[1]}")
        report.head("hosts' load")
        loads = host_loads(session, lab.realm)
        for line in format_loads(loads).splitlines():
            report.info(line)
        # The lab file's engines may name their context; arenas on request are their world's.
        contexts = {
            s.ident: s.params.get("context")
            for h in lab.hosts
            for s in h.services
            if s.kind == "engine"
        }
        report.head("services per host (as each host's supervisor sees them)")
        for load_ in loads:
            running = [name for name in load_.services if not name.endswith(" (down)")]
            report.info(f"{load_.host}: {', '.join(running) or 'no services'}")
            for name in load_.services:
                if name.endswith(" (down)"):
                    report.bad(
                        f"{name[: -len(' (down)')]} on {load_.host} is down (restarting); "
                        f"see its log in STATE_DIR/logs/ on {load_.host}"
                    )
            for arena in load_.arenas:
                # An arena is its engine and, with [arena] agent = true, its agent
                # context: both must be present for students to see and use it.
                wanted = [("engine", keys.alive(lab.realm, AliveKind.WORLD, arena.world))]
                if lab.arena.agent:
                    context = arena_context(arena.world, contexts.get(arena.world))
                    wanted.append(
                        ("agent context", keys.alive(lab.realm, AliveKind.CONTEXT, context))
                    )
                for what, key in wanted:
                    if key in live:
                        report.ok(f"arena {arena.world} on {load_.host}: {what} alive")
                    else:
                        report.bad(
                            f"arena {arena.world} on {load_.host}: its {what} is not alive "
                            f"({arena.state}); see the logs on {load_.host}"
                        )
        report.head("access denials")
        report.info(
            "routers drop denied messages silently; to see them, run wart host with "
            "RUST_LOG=zenoh::net::routing::interceptor=debug and read the router's log"
        )
        return report
    finally:
        for s in sessions:
            close_session(s)


def survey_main(options: NetworkOptions) -> int:
    """The lab-file-free check: what a plain client of the realm sees.

    When the realm is a ``wart up`` lab (its host ``local`` reports its load),
    every process of that lab's plan must be alive too.
    """
    try:
        session = open_session(options, wait=5.0)
    except ConnectionError as exc:
        print(f"✗ {exc}\n  is the lab running (wart up), and is --connect right?")
        return 1
    try:
        result = survey(session, options.realm)
        lines = result.lines()
        problems = list(result.problems)
        if any(load_.host == up.HOST_NAME for load_ in result.hosts):
            alive_all = keys.alive_all(options.realm)
            live = set(alive_keys(session, alive_all, what="services", timeout=3.0))
            lines.append(f"services of the `wart up` lab (host {up.HOST_NAME}):")
            for what, key in up_plan(options):
                if key in live:
                    lines.append(f"  ✓ {what} is alive")
                else:
                    lines.append(f"  ✗ {what} is not alive")
                    problems.append(f"{what} is not alive: see its log in STATE_DIR/logs/")
    finally:
        close_session(session)
    print("\n".join(lines))
    if problems:
        print(f"\n{len(problems)} problem(s)")
        for text in problems[len(result.problems) :]:
            print(f"  - {text}")
        return 1
    print("\nno problem found")
    return 0


def plugin_report() -> tuple[list[str], list[str]]:
    """This machine's plugins: (lines, problems), from the registry as the lab builds it."""
    reg = registry.build()
    plugins = sorted({origin for origin in reg.origins.values() if origin != registry.BUILT_IN})
    lines = ["plugins on this machine:"]
    lines += [f"  ✓ {origin}" for origin in plugins] or ["  (none installed)"]
    counts = (
        f"  {len(reg.robots)} robot types, {len(reg.components)} component types, "
        f"{len(reg.contexts)} plugin context types, {len(reg.engines)} plugin engine types"
    )
    lines.append(counts)
    problems = [f"plugin refused, the lab runs without it: {p}" for p in reg.problems]
    lines += [f"  ✗ {p}" for p in reg.problems]
    return lines, problems


def main(argv: Sequence[str] | None = None, prog: str = "wart doctor") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument("--lab", type=Path, help="the lab file (several hosts, TLS)")
    p.add_argument("--cert", default="admin", help="client certificate name (default admin)")
    p.add_argument("--plugins", action="store_true", help="check this machine's plugins only")
    args, options = cli.parse_networked(p, argv)
    lines, problems = plugin_report()
    print("\n".join(lines))
    if args.plugins:
        if problems:
            print(f"\n{len(problems)} problem(s):")
            print("\n".join(f"  - {text}" for text in problems))
            return 1
        print("\nno problem found")
        return 0
    print()
    if args.lab is None:
        code = survey_main(options)
        if problems:  # said again at the end, where the eye looks
            print("\n".join(f"  - {text}" for text in problems))
        return 1 if problems else code
    try:
        lab = load(args.lab)
        report = diagnose(lab, args.cert)
    except (LabFileError, FileNotFoundError) as exc:
        return cli.fail(str(exc))
    print("\n".join(report.lines))
    if report.problems or problems:
        every = [*report.problems, *problems]
        print(f"\n{len(every)} problem(s):")
        for text in every:
            print(f"  - {text}")
        return 1
    print("\nno problem found")
    return 0


if __name__ == "__main__":
    sys.exit(main())
