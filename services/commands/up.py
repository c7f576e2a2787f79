"""``wart up``: a whole lab on this machine, under supervision.

Starts a Zenoh router (unless ``--connect`` names an existing lab's router),
then every service of a lab, each as its own process; waits until each one's
liveliness token appears; prints one line per service and the web address;
restarts a child that dies (with backoff, and says so); stops them all in
order on Ctrl-C. Logs of each child go to STATE_DIR/logs/.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from common import cli
from common.auth import key_fingerprint
from common.service import stop_on_signals
from common.zconfig import DEFAULT_PORT, DEFAULT_REALM, DEFAULT_ROUTER, NetworkOptions
from services.lab import wiring
from services.lab.driver import HostDriver, say
from services.lab.hosting import HostingPlan, HostingService
from services.lab.lab_maps import SHIPPED_MAPS
from services.lab.labfile import ArenaSettings, Limits, ServiceEntry, service_entry
from services.lab.provision import provision_one_host
from services.lab.supervisor import Child, ChildSpec, Supervisor
from services.lab.wiring import (
    Wiring,
    default_state_dir,
    host_accounts,
    host_plan,
    host_waves,
)

log = logging.getLogger("wart.up")


@dataclass(frozen=True)
class LabSettings:
    """What ``wart up`` was asked for."""

    realm: str
    state_dir: Path
    router_endpoint: str  # where the children connect
    start_router: bool
    router_listen: tuple[str, ...]
    network: NetworkOptions  # what the children get (client mode, the router above)
    http_port: int
    lti: Path | None = None  # the LTI tool's platforms file: ``wart lti`` runs too
    lti_port: int = 8090


HOST_NAME = "local"  # the one-machine lab's host, on host/local/{spawn,load}
LOBBY = "lobby"
ARENA = "arena"  # the agent context on the simulated world
WORLD = "arena1"
RUNNER = "runner"
REAL_CONTEXT = "robots"  # the agent context on the real world
# The real-robot path without hardware: an emulated Khepera (Sim2D-backed, on a
# pty) exposed by a bridge as world REAL_WORLD; the emulator plays the first
# robot of its map, REAL_AGENT.
REAL_WORLD = "real1"
REAL_AGENT = "k1"
VIEWER_ID = "web"


def one_host_lab(
    http_port: int, lti: Path | None = None, lti_port: int = 8090
) -> tuple[ServiceEntry, ...]:
    """The lab ``wart up`` runs, written as a lab file's ``[[hosts.services]]`` tables.

    The worlds log in too (``login``): with an identity, agent contexts grant
    them MAC leases and commands cost µs to check instead of an Ed25519 verify.
    The lab's own contexts belong to its admin, who manages them from the page.
    """
    tables: list[dict[str, object]] = [
        {"kind": "registry"},
        {"kind": "chat", "name": LOBBY, "title": "Lobby", "owner": "admin"},
        {
            "kind": "engine",
            "world": WORLD,
            "map": "foraging",
            "context": ARENA,
            "title": "Arena (simulated)",
            "owner": "admin",
            "login": True,
        },
        {"kind": "runner", "name": RUNNER},
        {"kind": "grader"},
        {"kind": "bridge", "world": REAL_WORLD, "emulate": "empty", "login": True},
        {
            "kind": "agent",
            "name": REAL_CONTEXT,
            "world": REAL_WORLD,
            "title": "Khepera (real robot)",
            "owner": "admin",
        },
        # The viewer comes last: it is the front door once everything else serves.
        {"kind": "viewer", "name": VIEWER_ID, "http_port": http_port},
    ]
    if lti is not None:  # optional: a lab that takes launches from an LMS (docs/COURSES.md)
        tables.append({"kind": "lti", "platforms": str(lti.resolve()), "http_port": lti_port})
    return tuple(service_entry(f"wart up services[{i}]", t) for i, t in enumerate(tables))


def local_wiring(lab: LabSettings) -> Wiring:
    """Host ``local``: plain TCP to the lab's router, keys and maps in the state directory."""
    return Wiring(
        realm=lab.realm,
        host=HOST_NAME,
        state_dir=lab.state_dir,
        net_args=lambda _role: lab.network.as_args(),
        identity=lambda account: service_identity(lab, account),
        registry_key_file=lab.state_dir / "registry.key",
        map_dirs=(lab.state_dir / "maps", SHIPPED_MAPS),
        runner=RUNNER,
        arena=ArenaSettings(),
    )


def service_identity(lab: LabSettings, account: str) -> Path:
    return lab.state_dir / "identities" / f"{account}.key"


def service_accounts(lab: LabSettings) -> list[str]:
    """Every account the lab's processes log in with, those of contexts on request included."""
    services = one_host_lab(lab.http_port, lab.lti, lab.lti_port)
    return host_accounts(services, HOST_NAME, arenas=True, rooms=True)


def provision(lab: LabSettings) -> LabSettings:
    """What the registry and the services need before they start; idempotent.

    Creates the registry key (so every child gets ``--registry-key``), the
    database with an admin account (its password printed once and kept in
    STATE_DIR/admin-password.txt), and a service account with an identity key
    for each process that logs in. Returns the settings with the key pinned.
    """
    done = provision_one_host(
        lab.state_dir,
        lab.state_dir / "registry.key",
        {account: service_identity(lab, account) for account in service_accounts(lab)},
    )
    key_hex = done.registry.verify_key.hex()
    if lab.network.registry_key and lab.network.registry_key.lower() != key_hex:
        raise ValueError(
            f"--registry-key does not match this lab's key in {lab.state_dir / 'registry.key'}"
        )
    say(
        f"  registry key {'created' if done.key_created else 'loaded'}: {key_hex}\n"
        f"    (fingerprint {key_fingerprint(done.registry.verify_key)})"
    )
    if done.admin_password is not None:
        say(
            f"  first start: user 'admin', password {done.admin_password}\n"
            f"    (kept in {lab.state_dir / 'admin-password.txt'}); chat with\n"
            f"    wart chat {LOBBY} --user admin{client_flags(lab)} --registry-key {key_hex}"
        )
    else:
        say(f"  admin password: see {lab.state_dir / 'admin-password.txt'}")
    return replace(lab, network=lab.network.with_(registry_key=key_hex))


def client_flags(lab: LabSettings) -> str:
    """The flags a user's client needs to reach this lab, beyond the defaults."""
    flags = ""
    if lab.realm != DEFAULT_REALM:
        flags += f" --realm {lab.realm}"
    if lab.router_endpoint != DEFAULT_ROUTER:
        flags += f" --connect {lab.router_endpoint}"
    return flags


def lab_plan(lab: LabSettings) -> list[ChildSpec]:
    """The processes of the one-machine lab, in start order (the router is separate)."""
    return host_plan(local_wiring(lab), one_host_lab(lab.http_port, lab.lti, lab.lti_port))


def lab_waves(lab: LabSettings) -> list[list[ChildSpec]]:
    """The processes of the one-machine lab, in the waves they start in."""
    return host_waves(local_wiring(lab), one_host_lab(lab.http_port, lab.lti, lab.lti_port))


# The one machine is the whole lab: its operator chose to run it here, so the
# CPU does not refuse an arena (a busy laptop would otherwise refuse them all);
# count and free memory still do.
LOCAL_LIMITS = Limits(
    max_arenas_per_host=4,
    max_robots_per_arena=50,
    max_cpu_percent=100.0,
    min_free_memory_mb=256,
    load_period_s=5.0,
)
LOCAL_MAX_ROOMS = 16


def hosting_plan(lab: LabSettings) -> HostingPlan:
    """Host "local": arenas and chat rooms on request, sharing one account per kind."""
    if not lab.network.registry_key:
        raise ValueError("the lab's registry key is needed (provision first)")
    return HostingPlan(
        wiring=local_wiring(lab),
        registry_key=lab.network.registry_key,
        limits=LOCAL_LIMITS,
        max_rooms=LOCAL_MAX_ROOMS,
    )


def viewer_url(lab: LabSettings) -> str | None:
    try:
        return local_wiring(lab).viewer_url_file().read_text().strip() or None
    except OSError:
        return None


def router_spec(lab: LabSettings) -> ChildSpec:
    return wiring.router_spec(lab.realm, "lab-router", lab.router_listen)


def client_endpoint(listen: str) -> str:
    """Where a local client reaches a router listening on ``listen``."""
    proto, _, address = listen.partition("/")
    host, _, port = address.rpartition(":")
    if host in ("0.0.0.0", "[::]", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def settings_from_args(args: argparse.Namespace, options: NetworkOptions) -> LabSettings:
    state_dir: Path = args.state_dir or default_state_dir(options.realm)
    if options.connect:
        start_router = False
        router_endpoint = options.connect[0]
        router_listen: tuple[str, ...] = ()
    else:
        start_router = True
        router_listen = options.listen or (f"tcp/127.0.0.1:{args.port}",)
        router_endpoint = client_endpoint(router_listen[0])
    network = NetworkOptions(
        realm=options.realm,
        mode="client",
        connect=options.connect or (router_endpoint,),
        multicast_scouting=False,
        registry_key=options.registry_key,
    )
    return LabSettings(
        realm=options.realm,
        state_dir=state_dir,
        router_endpoint=router_endpoint,
        start_router=start_router,
        router_listen=router_listen,
        network=network,
        http_port=args.http_port,
        lti=getattr(args, "lti", None),
        lti_port=getattr(args, "lti_port", 8090),
    )


class LocalLab(HostDriver):
    """The one-machine lab under the shared driver (services/lab/driver.py): host "local"."""

    host_log = f"host-{HOST_NAME}.log"

    def __init__(self, lab: LabSettings) -> None:
        super().__init__(lab.realm, lab.state_dir)
        self.lab = lab  # provision() pins the registry key in it

    def banner(self) -> str:
        return f"wart lab '{self.realm}': state and logs in {self.state_dir}"

    def router(self) -> ChildSpec | None:
        return router_spec(self.lab) if self.lab.start_router else None

    def network(self) -> NetworkOptions:
        return self.lab.network

    def joined(self) -> str:
        return f"  joined the lab router at {self.lab.router_endpoint}"

    def provision(self) -> None:
        self.lab = provision(self.lab)
        # never report a previous run's URL
        local_wiring(self.lab).viewer_url_file().unlink(missing_ok=True)

    def waves(self) -> list[list[ChildSpec]]:
        return lab_waves(self.lab)

    def came_up(self, child: Child) -> None:
        if child.spec.name == "viewer":
            say(f"  web viewer: {viewer_url(self.lab) or '(address unknown)'}")

    def hosting(self, session: zenoh.Session, supervisor: Supervisor) -> HostingService:
        hosting = HostingService(session, hosting_plan(self.lab), supervisor).start()
        say(
            f"  ✓ {'hosting ' + HOST_NAME:<22} up  rooms and arenas on request "
            f"(host/{HOST_NAME}/spawn, `host` permission; log {self.host_log})"
        )
        return hosting

    def running(self) -> str:
        return "The lab is running. Press Ctrl-C to stop it."

    def stopping(self) -> str:
        return "Stopping the lab..."

    def stopped(self) -> str:
        return "Lab stopped."


def run_lab(
    lab: LabSettings, stop: threading.Event, *, ready: threading.Event | None = None
) -> int:
    """Start the lab, keep it running until ``stop`` is set, then stop it all."""
    return LocalLab(lab).run(stop, ready=ready)


def main(argv: Sequence[str] | None = None, prog: str = "wart up") -> int:
    p = cli.parser(prog, __doc__ or "")
    p.add_argument(
        "--state-dir",
        type=Path,
        help="where the lab keeps its database, keys and logs (default ~/.local/state/wart/REALM)",
    )
    p.add_argument(
        "--port",
        type=int,
        default=DEFAULT_PORT,
        help=f"the router's TCP port on 127.0.0.1 (default {DEFAULT_PORT})",
    )
    p.add_argument(
        "--http-port",
        type=int,
        default=8080,
        help="the web viewer's port (default 8080; the next free one if busy)",
    )
    p.add_argument(
        "--lti",
        type=Path,
        metavar="PLATFORMS",
        help="also run the LTI 1.3 tool (wart lti) with this platforms file (docs/COURSES.md)",
    )
    p.add_argument(
        "--lti-port", type=int, default=8090, help="the LTI tool's HTTP port (default 8090)"
    )
    args, options = cli.parse_networked(p, argv)
    if args.lti is not None and not args.lti.is_file():
        p.error(f"--lti {args.lti}: no such file")
    checks = ((args.port, "--port"), (args.http_port, "--http-port"), (args.lti_port, "--lti-port"))
    for port, what in checks:
        if not 0 < port < 65536:
            p.error(f"{what} {port} is not a TCP port (1 to 65535)")
    lab = settings_from_args(args, options)

    return run_lab(lab, stop_on_signals())


if __name__ == "__main__":
    sys.exit(main())
