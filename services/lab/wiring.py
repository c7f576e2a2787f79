"""Every process's command line and every service account's name, in one place.

Both ways of starting a lab go through here: ``wart host`` (a lab file's host:
TLS, the lab's PKI) and ``wart up`` (one machine: plain TCP on loopback, keys in
the state directory). What differs between them is a :class:`Wiring` (how a
child reaches the router and where its secrets are); what a registry, a chat
room, an arena, a bridge or a viewer is started with is written once, below.
A new flag on a service is one edit here.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common import keys
from common.acl import SERVICE_ACCOUNT_PREFIX as ACCOUNT_PREFIX
from common.keys import AliveKind
from services.lab.lab_maps import find_map, map_with_robots
from services.lab.labfile import ArenaSettings, LabFileError, ServiceEntry
from services.lab.supervisor import ChildSpec

# --- account names ----------------------------------------------------------------------


def service_account(kind: str, ident: str) -> str:
    """The account of a service named in a lab description (``chat-lobby``, ``ctx-robots``)."""
    return ACCOUNT_PREFIX[kind] + ident


def arena_account(host: str) -> str:
    """The one account the agent contexts of a host's arenas share."""
    return f"agent-{host}"


def room_account(host: str) -> str:
    """The one account the chat rooms a host starts on request share."""
    return f"room-{host}"


def logs_in(svc: ServiceEntry) -> bool:
    if svc.kind in ("engine", "bridge"):
        return bool(svc.params.get("login"))
    return svc.kind in ACCOUNT_PREFIX


def host_accounts(
    services: Iterable[ServiceEntry], host: str, *, arenas: bool, rooms: bool = False
) -> list[str]:
    """Every account a host's processes log in with.

    ``arenas``: the host runs arenas with agent contexts (which share one
    account); ``rooms``: it starts chat rooms on request (another shared one).
    """
    accounts = [service_account(s.kind, s.ident) for s in services if logs_in(s)]
    if arenas:
        accounts.append(arena_account(host))
    if rooms:
        accounts.append(room_account(host))
    return accounts


# --- how a host's children are wired ---------------------------------------------------


@dataclass(frozen=True)
class Wiring:
    """How the processes of one host reach the lab and find their secrets and files."""

    realm: str
    host: str
    state_dir: Path
    net_args: Callable[[str], list[str]]  # a role (engine, agent...) -> its network flags
    identity: Callable[[str], Path]  # an account -> its identity key file
    registry_key_file: Path
    map_dirs: tuple[Path, ...]  # where maps are looked up by name, in order
    runner: str  # the runner agent contexts use unless told
    arena: ArenaSettings
    # The viewer's public side; None: the viewer's own defaults (loopback).
    http_host: str | None = None
    lab_address: str | None = None

    @property
    def maps_dir(self) -> Path:
        """Where engines load and save maps by name (never the repository's maps/)."""
        return self.state_dir / "maps"

    @property
    def robots_dir(self) -> Path:
        """Robot types the lab's users saved (docs/ROBOTS.md): engines load and add to it."""
        return self.state_dir / "robots"

    @property
    def rooms_dir(self) -> Path:
        """Where chat rooms and agent contexts keep their history and queues."""
        return self.state_dir / "rooms"

    def login(self, account: str) -> list[str]:
        return ["--user", account, "--identity", str(self.identity(account))]

    def resolve_map(self, name: str) -> Path:
        """A map by plain name (never a path from the network)."""
        return find_map(name, self.map_dirs)

    def viewer_url_file(self) -> Path:
        """Where the viewer writes the page's actual URL (viser moves on if the port is busy)."""
        return self.state_dir / "viewer.url"


def default_state_dir(realm: str) -> Path:
    """Where a lab keeps its database, keys and logs unless told: ~/.local/state/wart/REALM."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "wart" / realm


def up_args(realm: str, state_dir: Path, port: int, http_port: int, *extra: str) -> list[str]:
    """``wart up``'s own arguments: a whole lab on this machine (tests, benchmarks)."""
    return [
        "up",
        "--realm",
        realm,
        "--state-dir",
        str(state_dir),
        "--port",
        str(port),
        "--http-port",
        str(http_port),
        *extra,
    ]


# --- one builder per process -------------------------------------------------------------


def router_spec(
    realm: str,
    name: str,
    listen: Sequence[str],
    *,
    connect: Sequence[str] = (),
    config: Path | None = None,
    detail: str | None = None,
) -> ChildSpec:
    argv = ["router", "--realm", realm, "--name", name]
    for endpoint in listen:
        argv += ["--listen", endpoint]
    if config is not None:
        argv += ["--config", str(config), "--no-multicast-scouting"]
    for endpoint in connect:
        argv += ["--connect", endpoint]
    return ChildSpec(
        name="router",
        argv=argv,
        alive_key=keys.alive(realm, AliveKind.ROUTER, name),
        detail=detail or ", ".join(listen),
    )


def registry_spec(
    w: Wiring, *, server_name: str | None = None, login_wait: float | None = None
) -> ChildSpec:
    argv = [
        "registry",
        "--db",
        str(w.state_dir / "registry.db"),
        "--key-file",
        str(w.registry_key_file),
        *w.net_args("registry"),
    ]
    if server_name:
        argv += ["--name", server_name]
    if login_wait is not None:
        argv += ["--login-wait", f"{login_wait:g}"]
    return ChildSpec("registry", argv, keys.alive(w.realm, AliveKind.REGISTRY, "registry"))


def chat_room_spec(
    w: Wiring,
    name: str,
    *,
    title: str | None = None,
    account: str | None = None,
    owner: str | None = None,
    detail: str | None = None,
) -> ChildSpec:
    """A chat room; account ``chat-NAME`` unless given, owned by ``owner`` (default the account)."""
    argv = [
        "context",
        "chat",
        "--name",
        name,
        *w.login(account or service_account("chat", name)),
        "--data-dir",
        str(w.rooms_dir),
        *w.net_args("chat"),
    ]
    if title:
        argv += ["--title", title]
    if owner:
        argv += ["--owner", owner]
    return ChildSpec(
        f"chat {name}", argv, keys.alive(w.realm, AliveKind.CONTEXT, name), detail or ""
    )


def plugin_context_spec(
    w: Wiring, name: str, kind: str, args: list[str], *, detail: str = ""
) -> ChildSpec:
    """A plugin's context type (``wart context KIND``) started on request: its name, a data
    directory of its own, the params its schema checked (common/robots/registry.py)."""
    argv = [
        "context",
        kind,
        "--name",
        name,
        "--data-dir",
        str(w.state_dir / "contexts" / name),
        *args,
        *w.net_args("chat"),  # the network a hosted chat room has (TLS: its certificate)
    ]
    return ChildSpec(
        f"{kind} {name}", argv, keys.alive(w.realm, AliveKind.CONTEXT, name), detail or kind
    )


def agent_context_spec(
    w: Wiring,
    name: str,
    world: str,
    *,
    title: str | None = None,
    runner: str | None = None,
    owner: str | None = None,
    slot_seconds: float | None = None,
    account: str | None = None,
    detail: str | None = None,
) -> ChildSpec:
    """An agent context: queues and leases for ``world``'s robots.

    Its account is ``ctx-NAME`` unless given (an arena's shares its host's).
    """
    argv = [
        "context",
        "agent",
        "--name",
        name,
        "--world",
        world,
        "--runner",
        runner or w.runner,
        *w.login(account or service_account("agent", name)),
        "--data-dir",
        str(w.rooms_dir),
        *w.net_args("agent"),
    ]
    if title:
        argv += ["--title", title]
    if slot_seconds:
        argv += ["--slot-seconds", f"{slot_seconds:g}"]
    if owner:
        argv += ["--owner", owner]
    return ChildSpec(
        f"agent context {name}",
        argv,
        keys.alive(w.realm, AliveKind.CONTEXT, name),
        detail=detail or f"queues and leases for the robots of {world}",
    )


def engine_spec(
    w: Wiring,
    world: str,
    map_path: Path,
    *,
    seed: int = 1,
    login: bool = False,
    drive: str | None = None,
    detail: str = "",
    prepare: Callable[[], object] | None = None,
) -> ChildSpec:
    """A simulated world; ``login`` gives it an account (``engine-WORLD``, MAC leases),
    ``drive`` its ``--drive`` (how its robots are driven: "discs" for a swarm)."""
    argv = [
        "engine",
        "--map",
        str(map_path),
        "--world",
        world,
        "--seed",
        str(seed),
        "--maps-dir",
        str(w.maps_dir),
        "--robots-dir",
        str(w.robots_dir),
        *w.net_args("engine"),
    ]
    if drive:
        argv += ["--drive", drive]
    if login:
        argv += w.login(service_account("engine", world))
    return ChildSpec(
        name=f"engine {world}",
        argv=argv,
        alive_key=keys.alive(w.realm, AliveKind.WORLD, world),
        detail=detail or f"simulated world {world} ({map_path.name})",
        # The first start of a checkout compiles the kernels: 37 s at load
        # 5 to 10 (25 s of CPU), over a minute on a busier machine.
        ready_timeout=ENGINE_READY_TIMEOUT_S,
        prepare=prepare,
    )


def arena_context(world: str, context: str | None = None) -> str:
    """The name of an arena's agent context: the world's unless the lab names another."""
    return context or world


def arena_specs(
    w: Wiring,
    world: str,
    map_path: Path,
    *,
    seed: int = 1,
    owner: str | None = None,
    context: str | None = None,
    title: str | None = None,
    login: bool = False,
    drive: str | None = None,
    prepare: Callable[[], object] | None = None,
) -> list[ChildSpec]:
    """An arena: the engine, then its agent context (unless the lab's arenas have none).

    ``context`` names the agent context (default: the world's name); it logs in
    with the account the host's arenas share; ``owner`` (the user who asked
    for the arena) may manage and kick there.
    """
    specs = [
        engine_spec(
            w,
            world,
            map_path,
            seed=seed,
            login=login,
            drive=drive,
            detail=f"simulated world {world} ({map_path.name})"
            + (f", for {owner}" if owner else ""),
            prepare=prepare,
        )
    ]
    if w.arena.agent:
        name = arena_context(world, context)
        specs.append(
            agent_context_spec(
                w,
                name,
                world,
                title=title or name,
                owner=owner,
                slot_seconds=w.arena.slot_seconds,
                account=arena_account(w.host),
                detail=f"agent context of {world}",
            )
        )
    return specs


def _own_account_spec(
    w: Wiring,
    kind: str,
    name: str,
    alive: AliveKind,
    account: str | None,
    extra: list[str],
    detail: str,
) -> ChildSpec:
    """``wart KIND --name NAME EXTRA``, logged in as ``account`` (default ``KIND-NAME``)."""
    argv = [kind, "--name", name, *w.login(account or service_account(kind, name)), *extra]
    return ChildSpec(
        f"{kind} {name}",
        [*argv, *w.net_args(kind)],
        keys.alive(w.realm, alive, name),
        detail=detail,
    )


def runner_spec(w: Wiring, name: str, *, account: str | None = None) -> ChildSpec:
    """A runner; its account is ``runner-NAME`` unless given."""
    return _own_account_spec(
        w, "runner", name, AliveKind.RUNNER, account, [], "sandboxed uploaded controllers"
    )


def grader_spec(
    w: Wiring, name: str = "grader", *, account: str | None = None, workers: int | None = None
) -> ChildSpec:
    """The grader; it reads and writes the registry's database, so it runs on its host."""
    extra = ["--db", str(w.state_dir / "registry.db")]
    if workers is not None:
        extra += ["--workers", str(workers)]
    return _own_account_spec(
        w, "grader", name, AliveKind.GRADER, account, extra, "submissions graded in simulation"
    )


def lti_spec(
    w: Wiring,
    platforms: Path,
    name: str = "lti",
    *,
    http_port: int = 8090,
    http_host: str = "127.0.0.1",
    account: str | None = None,
) -> ChildSpec:
    """The LTI 1.3 tool (services/lti/): its key and outbox in the state directory."""
    extra = ["--platforms", str(platforms), "--state-dir", str(w.state_dir / "lti")]
    extra += ["--http-host", http_host, "--http-port", str(http_port)]
    detail = f"LTI 1.3 tool on {http_host}:{http_port}"
    return _own_account_spec(w, "lti", name, AliveKind.LTI, account, extra, detail)


def viewer_spec(
    w: Wiring,
    ident: str,
    *,
    http_port: int = 8080,
    http_host: str | None = None,
    account: str | None = None,
) -> ChildSpec:
    """The web viewer; browsers elsewhere reach it on ``http_host`` (default ``w.http_host``).

    ``account``: its gateway account (it vouches for each browser's address at login).
    """
    http_host = http_host or w.http_host
    argv = ["viewer", "--id", ident, "--http-port", str(http_port)]
    if http_host:
        argv += ["--host", http_host]
    if w.lab_address:
        argv += ["--lab-address", w.lab_address]
    if account:
        argv += w.login(account)
    argv += [
        "--url-file",
        str(w.viewer_url_file()),
        "--data-dir",
        str(w.state_dir / "viewer"),
        *w.net_args("viewer"),
    ]
    return ChildSpec(
        "viewer",
        argv,
        keys.alive(w.realm, AliveKind.VIEWER, ident),
        detail=f"web viewer on {http_host or '127.0.0.1'}:{http_port}",
    )


# --- a lab description -> the processes ----------------------------------------------------


def service_specs(w: Wiring, svc: ServiceEntry) -> list[ChildSpec]:
    # Real arenas' specs build on this module's (a late import: no import cycle).
    from services.lab.real_arenas import bridge_specs, camera_spec

    """The processes of one service of a lab description (a lab file's or ``wart up``'s)."""
    p: Mapping[str, Any] = svc.params
    owner = str(p["owner"]) if p.get("owner") else None
    title = str(p["title"]) if p.get("title") else None
    if svc.kind == "registry":
        return [registry_spec(w, server_name=p.get("server_name"))]
    if svc.kind == "chat":
        return [chat_room_spec(w, str(p["name"]), title=title, owner=owner)]
    if svc.kind == "engine":
        world = str(p["world"])
        map_path = w.resolve_map(str(p["map"]))
        robots = int(p.get("robots", 0))
        prepare = None
        if robots:
            # Written when the engine starts, not now: planning writes nothing, so
            # the doctor can plan a host it does not run on.
            base, map_path = map_path, w.state_dir / "arenas" / f"{world}.json"
            prepare = functools.partial(map_with_robots, base, robots, map_path)
        return arena_specs(
            w,
            world,
            map_path,
            seed=int(p.get("seed", 1)),
            owner=owner,
            context=p.get("context"),
            title=title,
            login=bool(p.get("login")),
            drive=p.get("drive"),
            prepare=prepare,
        )
    if svc.kind == "bridge":
        return bridge_specs(
            w,
            svc.ident,
            [str(port) for port in p.get("ports", ())],
            emulate=p.get("emulate"),
            login=bool(p.get("login")),
            camera=bool(p.get("camera", True)),
        )
    if svc.kind == "camera":
        calibration = p.get("calibration")
        return [
            camera_spec(
                w,
                str(p["world"]),
                str(p["source"]),
                name=p.get("name"),
                calibration=None if calibration is None else Path(calibration),
                fps=p.get("fps"),
            )
        ]
    if svc.kind == "agent":
        slot = p.get("slot_seconds")
        return [
            agent_context_spec(
                w,
                svc.ident,
                str(p["world"]),
                title=title,
                runner=p.get("runner"),
                owner=owner,
                slot_seconds=float(slot) if slot else None,
            )
        ]
    if svc.kind == "runner":
        return [runner_spec(w, svc.ident)]
    if svc.kind == "grader":
        workers = p.get("workers")
        return [grader_spec(w, svc.ident, workers=None if workers is None else int(workers))]
    if svc.kind == "lti":
        port, host = int(p.get("http_port", 8090)), str(p.get("http_host") or "127.0.0.1")
        return [lti_spec(w, Path(p["platforms"]), svc.ident, http_port=port, http_host=host)]
    if svc.kind == "viewer":
        # The viewer's id defaults to its host's name: one viewer per host, and
        # the doctor knows which token to expect.
        return [
            viewer_spec(
                w,
                str(p.get("name") or w.host),
                http_port=int(p.get("http_port", 8080)),
                http_host=p.get("http_host"),
                account=service_account("viewer", svc.ident),
            )
        ]
    raise LabFileError(f"{svc.kind} services are not supported by this build")


# Worlds before the contexts that lease their robots; the viewer, the front
# door, once the rest serves.
ENGINE_READY_TIMEOUT_S = 240.0

START_ORDER = {
    "registry": 0,
    "chat": 1,
    "engine": 2,
    "bridge": 2,
    "camera": 3,
    "runner": 3,
    "grader": 3,
    "lti": 4,
    "agent": 4,
}


def host_plan(w: Wiring, services: Iterable[ServiceEntry]) -> list[ChildSpec]:
    """A host's services in start order (its router is started first, separately)."""
    specs: list[ChildSpec] = []
    for svc in sorted(services, key=lambda s: START_ORDER.get(s.kind, 5)):
        specs += service_specs(w, svc)
    return specs


def host_waves(w: Wiring, services: Iterable[ServiceEntry]) -> list[list[ChildSpec]]:
    """A host's services as waves started together, each once the one before serves.

    The registry goes first: every other service logs in to it. With it goes
    the viewer, the front door, whose login waits for the registry anyway:
    its address came 3 s sooner than when it imported beside eight other
    starting processes. The rest start at once, since each already
    waits for what it needs (a context for its world and runner, a bridge for
    its serial port): starting them one by one cost a lab's start 8 s on a
    quiet machine, 15 s on a busy one.
    """
    ordered = sorted(services, key=lambda s: START_ORDER.get(s.kind, 5))
    early = ("registry", "viewer")
    first = [spec for svc in ordered if svc.kind in early for spec in service_specs(w, svc)]
    rest = [spec for svc in ordered if svc.kind not in early for spec in service_specs(w, svc)]
    return [wave for wave in (first, rest) if wave]
