"""What ``wart host`` runs on one host, as data: child specs from the lab file.

Kept apart from the process (services/host.py) so tests and ``wart doctor``
can compute a host's plan without starting anything. The arena's processes
come from the lab file's ``[arena]`` templates (engine, and the agent context
once ``wart context agent`` exists), filled by :func:`arena_specs`.
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
from services.certs import identity_path, registry_key_path

REPO_MAPS = Path(__file__).resolve().parent.parent / "maps"

# The command each service kind needs, and the issue that brings it when absent.
NEEDS: dict[str, tuple[tuple[str, ...], str]] = {
    "registry": (("registry",), ""),
    "chat": (("context", "chat"), ""),
    "engine": (("engine",), ""),
    "bridge": (("bridge",), "issue 7 (the Khepera bridge on Zenoh)"),
    "viewer": (("viewer",), "issue 6 (the web viewer)"),
    "runner": (("runner",), "issue 5 (agent contexts and the runner)"),
}


def command_available(argv: tuple[str, ...] | list[str]) -> bool:
    """Whether ``wart ARGV[0] [ARGV[1]]`` exists in this build."""
    from services.cli import SUBCOMMANDS

    if not argv or argv[0] not in SUBCOMMANDS:
        return False
    if argv[0] == "context" and len(argv) > 1:
        from services.context import KINDS

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
        argv, issue = NEEDS[svc.kind]
        if not command_available(argv):
            raise LabFileError(
                f"hosts[{lab.hosts.index(host)}].services[{i}]: a {svc.kind} needs "
                f"`wart {' '.join(argv)}`, which this build does not have yet ({issue})"
            )
    if host.arenas and lab.arena.agent and not command_available(lab.arena.agent[:2]):
        raise LabFileError(
            f"arena.agent: `wart {' '.join(lab.arena.agent[:2])}` does not exist in this build "
            "(agent contexts land with issue 5); leave arena.agent empty until then"
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
    from services.certs import host_roles

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
    keys.check_ident("map", name)
    stem = name[:-5] if name.endswith(".json") else name
    for directory in (lab.maps_dir, REPO_MAPS):
        candidate = directory / f"{stem}.json"
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"no map named {name!r} in {lab.maps_dir} or {REPO_MAPS}")


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
    ctx: HostContext, world: str, map_path: Path, *, seed: int = 1, robots: int = 0
) -> list[ChildSpec]:
    """The processes of one arena: the engine, then the agent context (when configured)."""
    lab, host = ctx.lab, ctx.host
    account = f"agent-{host.name}"
    values = {
        "world": world,
        "map": map_path,
        "seed": seed,
        "robots": robots,
        "maps_dir": ctx.state_dir / "maps",
        "account": account,
        "identity": identity_path(lab.security.pki, host.name, account),
        "host": host.name,
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
        specs.append(
            ChildSpec(
                name=f"agent {world}",
                argv=[*fill(lab.arena.agent, values), *ctx.net_args("agent")],
                alive_key=keys.alive(ctx.realm, AliveKind.CONTEXT, world),
                detail=f"agent context of {world}",
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
    # bridge, viewer, runner: refused by check_available until their commands land.
    raise LabFileError(f"{svc.kind} services are not supported by this build yet")


def host_plan(ctx: HostContext) -> list[ChildSpec]:
    """The host's own services in start order (the router is started first, separately)."""
    order = {"registry": 0, "chat": 1, "engine": 2, "bridge": 2, "runner": 3, "viewer": 4}
    specs: list[ChildSpec] = []
    for svc in sorted(ctx.host.services, key=lambda s: order[s.kind]):
        specs += service_spec(ctx, svc)
    return specs
