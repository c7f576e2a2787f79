"""``wart up``: a whole lab on this machine, under supervision.

Starts a Zenoh router (unless ``--connect`` names an existing lab's router),
then every service of a lab, each as its own process; waits until each one's
liveliness token appears; prints one line per service and the web address;
restarts a child that dies (with backoff, and says so); stops them all in
order on Ctrl-C. Logs of each child go to STATE_DIR/logs/.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shutil
import signal
import sys
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from common import cli, keys
from common.keys import AliveKind
from common.labfile import Limits
from common.service import close_session, open_session
from common.supervisor import AliveWatch, ChildSpec, Supervisor
from common.zconfig import DEFAULT_PORT, DEFAULT_REALM, DEFAULT_ROUTER, NetworkOptions
from services.host.service import HostingPlan, HostingService
from services.lab.plan import find_map

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


def say(text: str) -> None:
    """One line for the operator; a closed terminal or pipe (``wart up | tee``,
    then Ctrl-C) must never interrupt an orderly stop."""
    with contextlib.suppress(BrokenPipeError, OSError):
        print(text, flush=True)


def default_state_dir(realm: str) -> Path:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "wart" / realm


LOBBY = "lobby"
ARENA = "arena"  # the agent context on the simulated world
WORLD = "arena1"
RUNNER = "runner"
REAL_CONTEXT = "robots"  # the agent context on the real world
# The real-robot path without hardware: an emulated Khepera (Sim2D-backed, on a
# pty whose stable link is KHEPERA_LINK in the state dir) exposed by a bridge as
# world REAL_WORLD, agent REAL_AGENT. The agent context for it uses these names.
REAL_WORLD = "real1"
# The worlds log in too (optional for them): with an identity, agent contexts
# grant MAC leases and commands cost µs to check instead of an Ed25519 verify.
# Contexts started on request (services/host/service.py) share one account per kind:
# an account may hold several sessions, and provisioning them here, before the
# registry starts, means nothing is registered while the lab runs.
HOST_NAME = "local"  # the one-machine lab's host, on host/local/{spawn,load}
HOSTED_ARENA_ACCOUNT = f"agent-{HOST_NAME}"  # the agent contexts of arenas on request
HOSTED_ROOM_ACCOUNT = f"room-{HOST_NAME}"  # chat rooms on request
SERVICE_ACCOUNTS = (
    f"chat-{LOBBY}",
    f"ctx-{ARENA}",
    f"ctx-{REAL_CONTEXT}",
    f"runner-{RUNNER}",
    f"engine-{WORLD}",
    f"bridge-{REAL_WORLD}",
    HOSTED_ARENA_ACCOUNT,
    HOSTED_ROOM_ACCOUNT,
)
REAL_AGENT = "k1"
REAL_MAP = "empty.json"


def khepera_link(lab: LabSettings) -> Path:
    return lab.state_dir / "dev" / "khepera0"


def service_identity(lab: LabSettings, account: str) -> Path:
    return lab.state_dir / "identities" / f"{account}.key"


def service_login(lab: LabSettings, account: str) -> list[str]:
    """The ``--user/--identity`` flags of a service account provisioned by ``provision``."""
    return ["--user", account, "--identity", str(service_identity(lab, account))]


SHIPPED_MAPS = Path(__file__).resolve().parents[2] / "maps"


def seed_maps(maps_dir: Path) -> None:
    """Copy the shipped maps into the lab's maps directory, never over a saved map.

    The engine loads and saves by name inside its maps directory; keeping that
    in the state dir leaves the repository's maps pristine.
    """
    maps_dir.mkdir(parents=True, exist_ok=True)
    for shipped in SHIPPED_MAPS.glob("*.json"):
        target = maps_dir / shipped.name
        if not target.exists():
            shutil.copyfile(shipped, target)


def provision(lab: LabSettings) -> LabSettings:
    """What the registry and the services need before they start; idempotent.

    Creates the registry key (so every child gets ``--registry-key``), the
    database with an admin account (its password printed once and kept in
    STATE_DIR/admin-password.txt), and a service account with an identity key
    for each context the lab runs. Returns the settings with the key pinned.
    """
    from common.auth import create_identity_key, key_fingerprint, load_identity_key
    from services.registry.service import provision as provision_registry

    seed_maps(lab.state_dir / "maps")
    identity, password, created = provision_registry(
        lab.state_dir / "registry.db", lab.state_dir / "registry.key"
    )
    key_hex = identity.verify_key.hex()
    if lab.network.registry_key and lab.network.registry_key.lower() != key_hex:
        raise ValueError(
            f"--registry-key does not match this lab's key in {lab.state_dir / 'registry.key'}"
        )
    khepera_link(lab).parent.mkdir(parents=True, exist_ok=True)
    accounts = {}
    for account in SERVICE_ACCOUNTS:
        path = service_identity(lab, account)
        key = load_identity_key(path) if path.exists() else create_identity_key(path)
        accounts[account] = bytes(key.verify_key)
    register_service_accounts(lab.state_dir / "registry.db", accounts)
    say(
        f"  registry key {'created' if created else 'loaded'}: {key_hex}\n"
        f"    (fingerprint {key_fingerprint(identity.verify_key)})"
    )
    if password is not None:
        say(
            f"  first start: user 'admin', password {password}\n"
            f"    (kept in {lab.state_dir / 'admin-password.txt'}); chat with\n"
            f"    wart chat {LOBBY} --user admin{client_flags(lab)} --registry-key {key_hex}"
        )
    else:
        say(f"  admin password: see {lab.state_dir / 'admin-password.txt'}")
    return replace(lab, network=lab.network.with_(registry_key=key_hex))


def register_service_accounts(db_path: Path, accounts: Mapping[str, bytes]) -> None:
    """Make sure each service account exists with the ``service`` role and its public key.

    Shared by ``wart up`` (its own services) and ``wart host`` (every service
    of a lab file, keys from the lab's PKI directory); idempotent.
    """
    from services.registry.accounts_db import RegistryDB

    db = RegistryDB(db_path)
    try:
        for account, public_key in accounts.items():
            if not db.user_exists(account):
                db.add_user(account, ["service"], public_key=public_key)
            else:
                db.add_key(account, public_key)
    finally:
        db.close()


def client_flags(lab: LabSettings) -> str:
    """The flags a user's client needs to reach this lab, beyond the defaults."""
    flags = ""
    if lab.realm != DEFAULT_REALM:
        flags += f" --realm {lab.realm}"
    if lab.router_endpoint != DEFAULT_ROUTER:
        flags += f" --connect {lab.router_endpoint}"
    return flags


def agent_context_spec(
    lab: LabSettings,
    name: str,
    title: str,
    world: str,
    *,
    account: str | None = None,
    owner: str | None = None,
) -> ChildSpec:
    """An agent context: queues and leases for the robots of ``world``.

    Its account is ``ctx-NAME`` unless given; ``owner`` (default: the account)
    may manage and kick there.
    """
    account = account or f"ctx-{name}"
    return ChildSpec(
        name=f"agent context {name}",
        argv=[
            "context",
            "agent",
            "--name",
            name,
            "--title",
            title,
            "--world",
            world,
            "--runner",
            RUNNER,
            "--user",
            account,
            "--identity",
            str(service_identity(lab, account)),
            "--data-dir",
            str(lab.state_dir / "rooms"),
            *(["--owner", owner] if owner else []),
            *lab.network.as_args(),
        ],
        alive_key=keys.alive(lab.realm, AliveKind.CONTEXT, name),
        detail=f"queues and leases for the robots of {world}",
    )


def chat_room_spec(
    lab: LabSettings, name: str, title: str, *, account: str | None = None, owner: str | None = None
) -> ChildSpec:
    """A chat room; account ``chat-NAME`` unless given, owned by ``owner`` (default the account)."""
    account = account or f"chat-{name}"
    return ChildSpec(
        name=f"chat {name}",
        argv=[
            "context",
            "chat",
            "--name",
            name,
            "--title",
            title,
            "--user",
            account,
            "--identity",
            str(service_identity(lab, account)),
            "--data-dir",
            str(lab.state_dir / "rooms"),
            *(["--owner", owner] if owner else []),
            *lab.network.as_args(),
        ],
        alive_key=keys.alive(lab.realm, AliveKind.CONTEXT, name),
    )


def engine_spec(lab: LabSettings, world: str, map_path: Path, *, seed: int = 1) -> list[str]:
    """The argv of a simulated world on ``map_path`` (saves go to the lab's maps dir)."""
    return [
        "engine",
        "--map",
        str(map_path),
        "--world",
        world,
        "--seed",
        str(seed),
        "--maps-dir",
        str(lab.state_dir / "maps"),
    ]


def lab_plan(lab: LabSettings) -> list[ChildSpec]:
    """The processes of a one-machine lab, in start order (the router is separate)."""
    realm = lab.realm
    net = lab.network.as_args()
    plan: list[ChildSpec] = []
    # Each service of the lab adds its entry here, after the ones it depends on.
    plan.append(
        ChildSpec(
            name="registry",
            argv=[
                "registry",
                "--db",
                str(lab.state_dir / "registry.db"),
                "--key-file",
                str(lab.state_dir / "registry.key"),
                *net,
            ],
            alive_key=keys.alive(realm, AliveKind.REGISTRY, "registry"),
        )
    )
    # The lab's own contexts belong to its admin, who manages them from the page.
    plan.append(chat_room_spec(lab, LOBBY, "Lobby", owner="admin"))
    plan.append(
        ChildSpec(
            name="engine",
            argv=[
                *engine_spec(lab, WORLD, lab.state_dir / "maps" / "foraging.json"),
                *service_login(lab, f"engine-{WORLD}"),
                *net,
            ],
            alive_key=keys.alive(realm, AliveKind.WORLD, WORLD),
            detail=f"simulated world {WORLD} (maps/foraging.json)",
        )
    )
    account = f"runner-{RUNNER}"
    plan.append(
        ChildSpec(
            name=RUNNER,
            argv=[
                "runner",
                "--name",
                RUNNER,
                "--user",
                account,
                "--identity",
                str(service_identity(lab, account)),
                *net,
            ],
            alive_key=keys.alive(realm, AliveKind.RUNNER, RUNNER),
            detail="sandboxed uploaded controllers",
        )
    )
    plan.append(agent_context_spec(lab, ARENA, "Arena (simulated)", WORLD, owner="admin"))
    link = khepera_link(lab)  # its directory is made by provision()
    plan.append(
        ChildSpec(
            name="khepera emulator",
            argv=[
                "khepera-emulator",
                "--map",
                str(lab.state_dir / "maps" / REAL_MAP),
                "--link",
                str(link),
            ],
            alive_key=None,  # not on the network: the bridge below is its presence
            detail=f"emulated Khepera at {link}",
        )
    )
    plan.append(
        ChildSpec(
            name=f"bridge {REAL_WORLD}",
            argv=[
                "bridge",
                "--world",
                REAL_WORLD,
                "--port",
                # The emulated robot stands at (500, 500) facing +x in its map: the
                # bridge's odometry starts there too, so both views agree.
                f"{link}={REAL_AGENT}@500,500,0",
                *service_login(lab, f"bridge-{REAL_WORLD}"),
                *net,
            ],
            alive_key=keys.alive(realm, AliveKind.WORLD, REAL_WORLD),
            detail=f"real world {REAL_WORLD}, robot {REAL_AGENT} (the emulated Khepera)",
        )
    )
    plan.append(
        agent_context_spec(lab, REAL_CONTEXT, "Khepera (real robot)", REAL_WORLD, owner="admin")
    )
    # The viewer comes last: it is the front door once everything else serves.
    plan.append(
        ChildSpec(
            name=VIEWER_NAME,
            argv=[
                "viewer",
                *net,
                "--id",
                "web",
                "--http-port",
                str(lab.http_port),
                "--url-file",
                str(viewer_url_file(lab)),
                "--data-dir",
                str(lab.state_dir / "viewer"),
            ],
            alive_key=keys.alive(realm, AliveKind.VIEWER, "web"),
        )
    )
    return plan


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


class LocalPlan(HostingPlan):
    """Host "local" of ``wart up``: maps from STATE/maps, the lab's runner, shared accounts."""

    def __init__(self, lab: LabSettings) -> None:
        if not lab.network.registry_key:
            raise ValueError("the lab's registry key is needed (provision first)")
        self.lab = lab
        self.realm = lab.realm
        self.host = HOST_NAME
        self.registry_key = lab.network.registry_key
        self.limits = LOCAL_LIMITS
        self.state_dir = lab.state_dir
        self.max_rooms = LOCAL_MAX_ROOMS

    def resolve_map(self, name: str) -> Path:
        return find_map(name, (self.lab.state_dir / "maps", SHIPPED_MAPS))

    def arena_specs(
        self, world: str, map_path: Path, *, seed: int, robots: int, owner: str
    ) -> list[ChildSpec]:
        engine = ChildSpec(
            name=f"engine {world}",
            argv=[*engine_spec(self.lab, world, map_path, seed=seed), *self.lab.network.as_args()],
            alive_key=keys.alive(self.realm, AliveKind.WORLD, world),
            detail=f"simulated world {world} ({map_path.name}), for {owner}",
        )
        context = agent_context_spec(
            self.lab, world, world, world, account=HOSTED_ARENA_ACCOUNT, owner=owner
        )
        return [engine, context]

    def room_specs(self, name: str, title: str, owner: str) -> list[ChildSpec]:
        spec = chat_room_spec(self.lab, name, title, account=HOSTED_ROOM_ACCOUNT, owner=owner)
        return [replace(spec, detail=f"chat room for {owner}")]


VIEWER_NAME = "viewer"


def viewer_url_file(lab: LabSettings) -> Path:
    """Where the viewer writes the page's actual URL (viser moves on if the port is busy)."""
    return lab.state_dir / "viewer.url"


def viewer_url(lab: LabSettings) -> str | None:
    try:
        return viewer_url_file(lab).read_text().strip() or None
    except OSError:
        return None


def router_spec(lab: LabSettings) -> ChildSpec:
    args = ["router", "--realm", lab.realm, "--name", "lab-router"]
    for endpoint in lab.router_listen:
        args += ["--listen", endpoint]
    return ChildSpec(
        name="router",
        argv=args,
        alive_key=keys.alive(lab.realm, AliveKind.ROUTER, "lab-router"),
        detail=", ".join(lab.router_listen),
    )


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
    )


def run_lab(
    lab: LabSettings, stop: threading.Event, *, ready: threading.Event | None = None
) -> int:
    """Start the lab, keep it running until ``stop`` is set, then stop it all."""
    lab.state_dir.mkdir(parents=True, exist_ok=True)
    supervisor = Supervisor(lab.state_dir / "logs", say=say)
    say(f"wart lab '{lab.realm}': state and logs in {lab.state_dir}")
    session = None
    hosting: HostingService | None = None
    code = 0
    try:
        if lab.start_router:
            supervisor.add(router_spec(lab))
            supervisor.spawn(supervisor.children[0])
        try:
            session = open_session(lab.network, wait=30.0, quiet=lab.start_router)
        except ConnectionError as exc:
            say(f"  ✗ {exc}")
            return 1
        supervisor.watch = AliveWatch(session, keys.alive_all(lab.realm))
        if lab.start_router and not supervisor.wait_ready(supervisor.children[0]):
            return 1
        if not lab.start_router:
            say(f"  joined the lab router at {lab.router_endpoint}")
        try:
            lab = provision(lab)
        except (ValueError, OSError) as exc:
            say(f"  ✗ {exc}")
            return 1
        viewer_url_file(lab).unlink(missing_ok=True)  # never report a previous run's URL
        for spec in lab_plan(lab):
            if stop.is_set():
                break
            if not supervisor.start(spec):
                code = 1
            elif spec.name == VIEWER_NAME:
                say(f"  web viewer: {viewer_url(lab) or '(address unknown)'}")
        if not stop.is_set():
            # In this process (not a child): its spawned contexts are this
            # supervisor's children, restarted and stopped with the rest.
            hosting = HostingService(session, LocalPlan(lab), supervisor).start()
            say(
                f"  ✓ {'hosting ' + HOST_NAME:<22} up  rooms and arenas on request "
                f"(host/{HOST_NAME}/spawn, `host` permission)"
            )
        if not stop.is_set():
            say("The lab is running. Press Ctrl-C to stop it.")
            if ready is not None:
                ready.set()
            supervisor.run_until(stop)
    finally:
        say("Stopping the lab...")
        if hosting is not None:
            hosting.stop()  # no new context starts while the children stop
        supervisor.stop_all()
        if session is not None:
            close_session(session)
        say("Lab stopped.")
    return code


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
    args, options = cli.parse(p, argv)
    assert options is not None
    for port, what in ((args.port, "--port"), (args.http_port, "--http-port")):
        if not 0 < port < 65536:
            p.error(f"{what} {port} is not a TCP port (1 to 65535)")
    lab = settings_from_args(args, options)

    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    return run_lab(lab, stop)


if __name__ == "__main__":
    sys.exit(main())
