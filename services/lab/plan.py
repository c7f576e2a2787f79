"""What ``wart host`` runs on one host, as data: child specs from the lab file.

Kept apart from the process (services/host/main.py) so tests and ``wart doctor``
can compute a host's plan without starting anything. The arena's processes
come from the lab file's ``[arena]`` templates (engine and agent context),
filled by :func:`arena_specs`; an engine named in the lab file is an arena too.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from common import keys
from common.keys import AliveKind
from common.labfile import HostEntry, LabFile, LabFileError, ServiceEntry, fill
from common.supervisor import ChildSpec
from common.zsecurity import acl_config, host_tls, write_config, zenoh_security
from services.commands.certs import identity_path, registry_key_path

REPO_MAPS = Path(__file__).resolve().parents[2] / "maps"

# The command each service kind needs (a build without one refuses the host).
NEEDS: dict[str, tuple[str, ...]] = {
    "registry": ("registry",),
    "chat": ("context", "chat"),
    "engine": ("engine",),
    "bridge": ("bridge",),
    "agent": ("context", "agent"),
    "viewer": ("viewer",),
    "runner": ("runner",),
}
# Where an emulated Khepera's robot starts when its map names none (the bridge's
# odometry must start where the emulated body is, or the two views disagree).
DEFAULT_POSE = (500.0, 500.0, 0.0)


def command_available(argv: tuple[str, ...] | list[str]) -> bool:
    """Whether ``wart ARGV[0] [ARGV[1]]`` exists in this build."""
    from services.cli import SUBCOMMANDS

    if not argv or argv[0] not in SUBCOMMANDS:
        return False
    if argv[0] == "context" and len(argv) > 1:
        from services.context.main import KINDS

        return argv[1] in KINDS
    return True


@dataclass(frozen=True)
class HostContext:
    """Everything a host's children need, resolved once at start."""

    lab: LabFile
    host: HostEntry
    state_dir: Path
    registry_key: str  # hex, pinned by every child

    @property
    def realm(self) -> str:
        return self.lab.realm

    def config_path(self, role: str) -> Path:
        return self.state_dir / "zenoh" / f"{role}.json5"

    def net_args(self, role: str) -> list[str]:
        """What a client child on this host gets: its role's TLS config, the local router."""
        return [
            "--realm",
            self.realm,
            "--mode",
            "client",
            "--connect",
            self.host.local_endpoint,
            "--config",
            str(self.config_path(role)),
            "--no-multicast-scouting",
            "--registry-key",
            self.registry_key,
        ]


def read_registry_key(lab: LabFile) -> str:
    path = lab.security.pki / "registry.pub"
    try:
        text = path.read_text().strip()
    except OSError:
        raise LabFileError(
            f"{path} is missing: run `wart certs lab --lab {lab.path}` and copy the PKI directory"
        ) from None
    if len(text) != 64 or any(c not in "0123456789abcdef" for c in text.lower()):
        raise LabFileError(f"{path} does not hold a registry public key (64 hex digits)")
    return text.lower()


def check_available(lab: LabFile, host: HostEntry) -> None:
    """Refuse, before anything starts, a host whose share needs a command this build lacks."""
    for i, svc in enumerate(host.services):
        argv = NEEDS[svc.kind]
        if not command_available(argv):
            raise LabFileError(
                f"hosts[{lab.hosts.index(host)}].services[{i}]: a {svc.kind} needs "
                f"`wart {' '.join(argv)}`, which this build does not have"
            )
    for which, template in (("engine", lab.arena.engine), ("agent", lab.arena.agent)):
        if template and not command_available(template[:2]):
            raise LabFileError(
                f"arena.{which}: `wart {' '.join(template[:2])}` does not exist in this build"
            )


def write_configs(ctx: HostContext) -> None:
    """The Zenoh config of every process role on this host (TLS, lease; ACL for the router)."""
    lab, host = ctx.lab, ctx.host
    pki = lab.security.pki
    acl = None
    if lab.security.acl:
        names: dict[str, tuple[str, ...]] = {
            "student": lab.security.student_names,
            "admin": lab.security.admin_names,
        }
        acl = acl_config(lab.realm, names)
    from services.commands.certs import host_roles

    for role in host_roles(lab, host.name):
        conf = zenoh_security(
            host_tls(pki, host.name, role),
            lease_ms=lab.lease_ms,
            acl=acl if role == "router" else None,
        )
        # The doctor names routers by this (the admin space shows it with the links).
        conf["metadata"] = {"name": host.name, "role": role, "realm": lab.realm}
        write_config(ctx.config_path(role), conf)


def router_spec(ctx: HostContext) -> ChildSpec:
    host = ctx.host
    argv = [
        "router",
        "--realm",
        ctx.realm,
        "--name",
        host.name,
        "--listen",
        f"tls/0.0.0.0:{host.port}",
        "--config",
        str(ctx.config_path("router")),
        "--no-multicast-scouting",
    ]
    for other in host.connect:
        argv += ["--connect", ctx.lab.host(other).endpoint]
    return ChildSpec(
        name="router",
        argv=argv,
        alive_key=keys.alive(ctx.realm, AliveKind.ROUTER, host.name),
        detail=f"tls/0.0.0.0:{host.port}"
        + (f", meshed with {', '.join(host.connect)}" if host.connect else ""),
    )


def resolve_map(lab: LabFile, name: str) -> Path:
    """A map by plain name (never a path from the network): the lab's, then the shipped ones."""
    return find_map(name, (lab.maps_dir, REPO_MAPS))


def find_map(name: str, directories: tuple[Path, ...]) -> Path:
    """``NAME.json`` in the first directory that has it; the name is one key chunk, not a path."""
    keys.check_ident("map", name)
    stem = name[:-5] if name.endswith(".json") else name
    for directory in directories:
        candidate = directory / f"{stem}.json"
        if candidate.is_file():
            return candidate
    where = " or ".join(str(d) for d in directories)
    raise FileNotFoundError(f"map {name!r} not found (looked in {where})")


def map_with_robots(base: Path, robots: int, out: Path) -> Path:
    """A copy of a map whose robots are replaced by ``robots`` Khepera on a grid."""
    data: dict[str, Any] = json.loads(base.read_text())
    width, height = data["arena"]["width"], data["arena"]["height"]
    data.pop("agents", None)
    data["agent_groups"] = [
        {
            "type": "khepera",
            "count": robots,
            "prefix": "k",
            "area": [100, 100, width - 100, height - 100],
            "spacing": 90,
            "gripper": False,
        }
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(data, indent=1))
    return out


def arena_specs(
    ctx: HostContext,
    world: str,
    map_path: Path,
    *,
    seed: int = 1,
    robots: int = 0,
    owner: str | None = None,
) -> list[ChildSpec]:
    """The processes of one arena: the engine, then the agent context (when configured).

    ``owner`` (the user who asked for the arena) becomes the agent context's
    owner, so they can manage and kick there; a template that does not place
    ``{owner}`` itself gets ``--owner`` appended.
    """
    lab, host = ctx.lab, ctx.host
    account = arena_account(host.name)
    values = {
        "world": world,
        "map": map_path,
        "seed": seed,
        "robots": robots,
        "maps_dir": ctx.state_dir / "maps",
        "account": account,
        "identity": identity_path(lab.security.pki, host.name, account),
        "host": host.name,
        "runner": lab.runner_for(host.name),
        "owner": owner or account,
    }
    specs = [
        ChildSpec(
            name=f"engine {world}",
            argv=[*fill(lab.arena.engine, values), *ctx.net_args("engine")],
            alive_key=keys.alive(ctx.realm, AliveKind.WORLD, world),
            detail=f"simulated world {world} ({map_path.name})",
        )
    ]
    if lab.arena.agent:
        argv = fill(lab.arena.agent, values)
        if owner and not any("{owner}" in arg for arg in lab.arena.agent):
            argv += ["--owner", owner]
        specs.append(
            ChildSpec(
                name=f"agent {world}",
                argv=[*argv, *ctx.net_args("agent")],
                alive_key=keys.alive(ctx.realm, AliveKind.CONTEXT, world),
                detail=f"agent context of {world}",
            )
        )
    return specs


def arena_account(host: str) -> str:
    """The one service account the agent contexts of a host's arenas share."""
    return f"agent-{host}"


def map_pose(map_path: Path) -> tuple[float, float, float]:
    """Where the map's first robot stands (x mm, y mm, heading degrees)."""
    data: dict[str, Any] = json.loads(map_path.read_text())
    for agent in data.get("agents", []):
        return (
            float(agent.get("x", DEFAULT_POSE[0])),
            float(agent.get("y", DEFAULT_POSE[1])),
            float(agent.get("heading_deg", DEFAULT_POSE[2])),
        )
    return DEFAULT_POSE


def emulator_link(ctx: HostContext, world: str) -> Path:
    """The stable path of an emulated Khepera's pty (what a real one's by-id path would be)."""
    return ctx.state_dir / "dev" / f"{world}-khepera"


def bridge_specs(ctx: HostContext, svc: ServiceEntry) -> list[ChildSpec]:
    """A bridge, preceded by the emulated Khepera it drives when the lab has no hardware."""
    p, world = svc.params, svc.ident
    ports = [str(port) for port in p.get("ports", ())]
    specs: list[ChildSpec] = []
    if p.get("emulate"):
        map_path = resolve_map(ctx.lab, str(p["emulate"]))
        link = emulator_link(ctx, world)
        link.parent.mkdir(parents=True, exist_ok=True)
        x, y, deg = map_pose(map_path)
        specs.append(
            ChildSpec(
                name=f"khepera emulator {world}",
                argv=["khepera-emulator", "--map", str(map_path), "--link", str(link)],
                alive_key=None,  # not on the network: the bridge below is its presence
                detail=f"emulated Khepera at {link} ({map_path.name})",
            )
        )
        taken = {port.partition("=")[2].partition("@")[0] for port in ports}
        agent = next(f"k{n}" for n in range(1, len(ports) + 2) if f"k{n}" not in taken)
        ports.append(f"{link}={agent}@{x:g},{y:g},{deg:g}")
    argv = ["bridge", "--world", world]
    for port in ports:
        argv += ["--port", port]
    specs.append(
        ChildSpec(
            name=f"bridge {world}",
            argv=[*argv, *ctx.net_args("bridge")],
            alive_key=keys.alive(ctx.realm, AliveKind.WORLD, world),
            detail=f"real world {world}, {len(ports)} robot(s)"
            + (" (one emulated)" if p.get("emulate") else ""),
        )
    )
    return specs


def service_spec(ctx: HostContext, svc: ServiceEntry) -> list[ChildSpec]:
    lab, host, state = ctx.lab, ctx.host, ctx.state_dir
    p = svc.params
    if svc.kind == "registry":
        argv = [
            "registry",
            "--db",
            str(state / "registry.db"),
            "--key-file",
            str(registry_key_path(lab)),
            *ctx.net_args("registry"),
        ]
        if p.get("server_name"):
            argv += ["--name", str(p["server_name"])]
        return [ChildSpec("registry", argv, keys.alive(ctx.realm, AliveKind.REGISTRY, "registry"))]
    if svc.kind == "chat":
        room, account = str(p["name"]), f"chat-{p['name']}"
        argv = [
            "context",
            "chat",
            "--name",
            room,
            "--user",
            account,
            "--identity",
            str(identity_path(lab.security.pki, host.name, account)),
            "--data-dir",
            str(state / "rooms"),
            *ctx.net_args("chat"),
        ]
        if p.get("title"):
            argv += ["--title", str(p["title"])]
        return [ChildSpec(f"chat {room}", argv, keys.alive(ctx.realm, AliveKind.CONTEXT, room))]
    if svc.kind == "engine":
        map_path = resolve_map(lab, str(p["map"]))
        robots = int(p.get("robots", 0))
        if robots:
            map_path = map_with_robots(map_path, robots, state / "arenas" / f"{p['world']}.json")
        return arena_specs(ctx, str(p["world"]), map_path, seed=int(p.get("seed", 1)))
    if svc.kind == "bridge":
        return bridge_specs(ctx, svc)
    if svc.kind == "agent":
        name, account = svc.ident, f"ctx-{svc.ident}"
        argv = [
            "context",
            "agent",
            "--name",
            name,
            "--world",
            str(p["world"]),
            "--runner",
            str(p.get("runner") or lab.runner_for(host.name)),
            "--user",
            account,
            "--identity",
            str(identity_path(lab.security.pki, host.name, account)),
            "--data-dir",
            str(state / "rooms"),
            *ctx.net_args("agent"),
        ]
        if p.get("title"):
            argv += ["--title", str(p["title"])]
        if p.get("slot_seconds"):
            argv += ["--slot-seconds", f"{float(p['slot_seconds']):g}"]
        return [
            ChildSpec(
                f"agent context {name}",
                argv,
                keys.alive(ctx.realm, AliveKind.CONTEXT, name),
                detail=f"queues and leases for the robots of {p['world']}",
            )
        ]
    if svc.kind == "runner":
        name, account = svc.ident, f"runner-{svc.ident}"
        argv = [
            "runner",
            "--name",
            name,
            "--user",
            account,
            "--identity",
            str(identity_path(lab.security.pki, host.name, account)),
            *ctx.net_args("runner"),
        ]
        return [
            ChildSpec(
                f"runner {name}",
                argv,
                keys.alive(ctx.realm, AliveKind.RUNNER, name),
                detail="sandboxed uploaded controllers",
            )
        ]
    if svc.kind == "viewer":
        # The viewer's id is its host's name: one viewer per host, and the doctor
        # knows which token to expect. Browsers elsewhere reach it on the host's
        # address (http_host), and it offers them this lab by the same address.
        http_host = str(p.get("http_host") or host.address)
        argv = [
            "viewer",
            "--id",
            host.name,
            "--http-port",
            str(p.get("http_port", 8080)),
            "--host",
            http_host,
            "--lab-address",
            f"{host.address}:{host.port}/{ctx.realm}",
            "--url-file",
            str(state / "viewer.url"),
            "--data-dir",
            str(state / "viewer"),
            *ctx.net_args("viewer"),
        ]
        return [
            ChildSpec(
                "viewer",
                argv,
                keys.alive(ctx.realm, AliveKind.VIEWER, host.name),
                detail=f"web viewer on {http_host}:{p.get('http_port', 8080)}",
            )
        ]
    raise LabFileError(f"{svc.kind} services are not supported by this build")


def host_plan(ctx: HostContext) -> list[ChildSpec]:
    """The host's own services in start order (the router is started first, separately)."""
    # Worlds before the contexts that lease their robots; the viewer, the front
    # door, once the rest serves.
    order = dict(registry=0, chat=1, engine=2, bridge=2, runner=3, agent=4, viewer=5)
    specs: list[ChildSpec] = []
    for svc in sorted(ctx.host.services, key=lambda s: order[s.kind]):
        specs += service_spec(ctx, svc)
    return specs
