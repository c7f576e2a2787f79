"""What ``wart host`` runs on one host, as data: child specs from the lab file.

Kept apart from the process (services/host/main.py) so tests and ``wart doctor``
can compute a host's plan without starting anything. What is lab-file specific
lives here (its TLS configs, its PKI, its registry key); the command lines
themselves come from services/lab/wiring.py, which ``wart up`` uses too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from common.zconfig import NetworkOptions
from services.cli import SUBCOMMANDS
from services.lab import wiring
from services.lab.lab_maps import SHIPPED_MAPS, find_map
from services.lab.labfile import HostEntry, LabFile, LabFileError
from services.lab.pki import host_roles, identity_path, registry_key_path
from services.lab.supervisor import ChildSpec
from services.lab.wiring import Wiring, default_state_dir
from services.lab.zsecurity import acl_config, host_tls, write_config, zenoh_security

# The command each service kind needs (a build without one refuses the host).
NEEDS: dict[str, tuple[str, ...]] = {
    "registry": ("registry",),
    "chat": ("context", "chat"),
    "engine": ("engine",),
    "bridge": ("bridge",),
    "agent": ("context", "agent"),
    "viewer": ("viewer",),
    "runner": ("runner",),
    "camera": ("camera",),
}


def command_available(argv: tuple[str, ...] | list[str]) -> bool:
    """Whether ``wart ARGV[0]`` exists in this build (``wart context`` has every kind a lab
    file names: chat and agent are its own)."""
    return bool(argv) and argv[0] in SUBCOMMANDS


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

    def network(self, role: str) -> NetworkOptions:
        """What a process of this host gets: its role's TLS config, the local router."""
        return NetworkOptions(
            realm=self.realm,
            mode="client",
            connect=(self.host.local_endpoint,),
            config_file=self.config_path(role),
            registry_key=self.registry_key,
        )

    def net_args(self, role: str) -> list[str]:
        return self.network(role).as_args()

    def wiring(self) -> Wiring:
        """This host's children: TLS to the local router, identities from the lab's PKI."""
        lab, host = self.lab, self.host
        return Wiring(
            realm=lab.realm,
            host=host.name,
            state_dir=self.state_dir,
            net_args=self.net_args,
            identity=lambda account: identity_path(lab.security.pki, host.name, account),
            registry_key_file=registry_key_path(lab),
            map_dirs=(lab.maps_dir, SHIPPED_MAPS),
            runner=lab.runner_for(host.name),
            arena=lab.arena,
            http_host=host.address,
            lab_address=f"{host.address}:{host.port}/{lab.realm}",
        )


def host_state_dir(lab: LabFile, host: HostEntry, override: Path | None = None) -> Path:
    """Where a host keeps its database, logs and configs: ``--state-dir``, else the lab
    file's ``state_dir``/HOST, else ~/.local/state/wart/REALM/HOST."""
    if override is not None:
        return override
    if lab.state_dir is not None:
        return lab.state_dir / host.name
    return default_state_dir(lab.realm) / host.name


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
    if lab.arena.agent and not command_available(NEEDS["agent"]):
        raise LabFileError(
            "arena.agent: arenas' agent contexts need `wart context agent`, "
            "which this build does not have"
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
    return wiring.router_spec(
        ctx.realm,
        host.name,
        [f"tls/0.0.0.0:{host.port}"],
        connect=[ctx.lab.host(other).endpoint for other in host.connect],
        config=ctx.config_path("router"),
        detail=f"tls/0.0.0.0:{host.port}"
        + (f", meshed with {', '.join(host.connect)}" if host.connect else ""),
    )


def resolve_map(lab: LabFile, name: str) -> Path:
    """A map by plain name (never a path from the network): the lab's, then the shipped ones."""
    return find_map(name, (lab.maps_dir, SHIPPED_MAPS))


def host_plan(ctx: HostContext) -> list[ChildSpec]:
    """The host's own services in start order (the router is started first, separately)."""
    return wiring.host_plan(ctx.wiring(), ctx.host.services)


def host_waves(ctx: HostContext) -> list[list[ChildSpec]]:
    """The host's own services in the waves they start in (see ``wiring.host_waves``)."""
    return wiring.host_waves(ctx.wiring(), ctx.host.services)
