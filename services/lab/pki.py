"""The lab's PKI directory: which certificates and keys each host of a lab file needs.

The library behind ``wart certs lab`` (services/commands/certs.py) that ``wart host``
(services/lab/plan.py, services/host/main.py) reads too: where a host's service
identities are, where the registry's key is, and issuing all of it at once. It
lives here, not with the command, because the lab library never imports a command.
"""

from __future__ import annotations

import json
from pathlib import Path

from common.auth import RegistryIdentity, create_identity_key, load_identity_key
from services.lab.certs import CA_KEY, init_ca, issue
from services.lab.labfile import LabFile
from services.lab.wiring import host_accounts
from services.lab.zsecurity import ROLES

REGISTRY_PUB = "registry.pub"
ACCOUNTS = "accounts.json"


def host_roles(lab: LabFile, host: str) -> list[str]:
    """The certificates a host needs: its router, its supervisor, its services, arenas."""
    entry = lab.host(host)
    roles = ["router", "host", *sorted(entry.kinds())]
    if any(s.kind == "bridge" and s.params.get("emulate") and s.params.get("camera", True)
           for s in entry.services):  # fmt: skip
        roles.append("camera")  # the emulated arena's synthetic camera
    if entry.arenas or "engine" in entry.kinds():
        roles += ["engine", "agent"]  # an engine is an arena: its agent context comes along
    return sorted(set(roles), key=ROLES.index)


def service_accounts(lab: LabFile, host: str) -> list[str]:
    """The registry accounts of a host's services: chat rooms, agent contexts, runners,
    engines and bridges that log in, and the one its arenas' agent contexts share (also
    for engines the lab file names)."""
    entry = lab.host(host)
    arenas = bool(lab.arena.agent) and (entry.arenas or "engine" in entry.kinds())
    return host_accounts(entry.services, host, arenas=arenas)


def identity_path(pki: Path, host: str, account: str) -> Path:
    return pki / host / "identities" / f"{account}.key"


def registry_key_path(lab: LabFile) -> Path:
    return lab.security.pki / lab.registry_host().name / "identities" / "registry.key"


def issue_lab(lab: LabFile, *, say: object = print) -> None:
    """Issue every certificate and key the lab file needs (re-issues existing ones)."""
    pki = lab.security.pki
    out = say if callable(say) else print
    if not (pki / CA_KEY).exists():
        init_ca(pki, f"wart {lab.realm} CA")
        out(f"created the CA in {pki}")
    accounts: dict[str, str] = {}
    for host in lab.hosts:
        alt = [host.address, *host.names]
        for role in host_roles(lab, host.name):
            issued = issue(pki, role, alt_names=alt, out_dir=pki / host.name)
            out(f"  {host.name}: {role:<9} {issued.cert} (until {issued.not_after:%Y-%m-%d})")
        for account in service_accounts(lab, host.name):
            path = identity_path(pki, host.name, account)
            key = load_identity_key(path) if path.exists() else create_identity_key(path)
            accounts[account] = bytes(key.verify_key).hex()
    for name in lab.security.student_names + lab.security.admin_names:
        issued = issue(pki, name, out_dir=pki / "clients")
        out(f"  client:  {name:<9} {issued.cert}")
    identity, created = RegistryIdentity.load_or_create(registry_key_path(lab))
    (pki / REGISTRY_PUB).write_text(identity.verify_key.hex() + "\n")
    (pki / ACCOUNTS).write_text(json.dumps(accounts, indent=2, sort_keys=True) + "\n")
    out(
        f"  registry key {'created' if created else 'kept'}: {registry_key_path(lab)}; "
        f"public key in {pki / REGISTRY_PUB}"
    )
