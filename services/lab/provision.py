"""What a lab needs on disk before its services start: maps, keys, accounts.

One module for both ways of starting a lab. ``wart up`` makes everything in
its state directory (the registry key, an identity key per service account);
``wart host`` on the registry's host takes the keys ``wart certs lab`` made in
the lab's PKI directory. Either way the registry database gets its admin
account and every service account, before the registry starts, so nothing is
registered while the lab runs. Every step is idempotent: a second start loads
what the first one made.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from common.auth import RegistryIdentity, create_identity_key, load_identity_key
from services.lab.lab_maps import SHIPPED_MAPS
from services.lab.labfile import LabFileError
from services.lab.wiring import ACCOUNT_PREFIX
from services.registry.accounts_db import RegistryDB
from services.registry.accounts_db import provision as provision_registry_db


@dataclass(frozen=True)
class Provisioned:
    """What a start found or made: the registry's identity, and the admin's first password."""

    registry: RegistryIdentity
    admin_password: str | None  # only on the very first start; also in admin-password.txt
    key_created: bool


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


def register_service_accounts(db_path: Path, accounts: Mapping[str, bytes]) -> None:
    """Make sure each service account exists with its role and its public key.

    The role is ``service``, but a viewer's (``viewer-*``) is ``gateway``: a
    process facing browsers gets no right to lease, serve worlds or run code;
    the LTI tool's (``lti-*``) is ``lti``, for the same reason.
    """
    db = RegistryDB(db_path)
    try:
        for account, public_key in accounts.items():
            role = "gateway" if account.startswith(ACCOUNT_PREFIX["viewer"]) else "service"
            if account.startswith(ACCOUNT_PREFIX["lti"]):
                role = "lti"  # asks the registry for launched LMS users' accounts, nothing else
            if not db.user_exists(account):
                db.add_user(account, [role], public_key=public_key)
            else:
                db.add_key(account, public_key)
    finally:
        db.close()


def identity_keys(paths: Mapping[str, Path]) -> dict[str, bytes]:
    """Each account's identity key, created where missing; the public halves."""
    public: dict[str, bytes] = {}
    for account, path in paths.items():
        key = load_identity_key(path) if path.exists() else create_identity_key(path)
        public[account] = bytes(key.verify_key)
    return public


def provision_one_host(
    state_dir: Path, registry_key_file: Path, identities: Mapping[str, Path]
) -> Provisioned:
    """``wart up``'s lab: maps, the registry key and DB, and the given service accounts."""
    seed_maps(state_dir / "maps")
    identity, password, created = provision_registry_db(
        state_dir / "registry.db", registry_key_file
    )
    register_service_accounts(state_dir / "registry.db", identity_keys(identities))
    return Provisioned(identity, password, created)


def provision_registry_host(
    state_dir: Path, registry_key_file: Path, accounts_file: Path, expected_key: str
) -> Provisioned:
    """A lab file's registry host: the DB, its admin, and every service account of the lab.

    The public keys come from ``accounts_file`` (``wart certs lab`` wrote it);
    ``expected_key`` is the registry public key every host pins.
    """
    identity, password, created = provision_registry_db(
        state_dir / "registry.db", registry_key_file
    )
    if identity.verify_key.hex() != expected_key:
        raise LabFileError(f"{registry_key_file} does not match the lab's registry.pub")
    try:
        accounts = {
            name: bytes.fromhex(hexkey)
            for name, hexkey in json.loads(accounts_file.read_text()).items()
        }
    except (OSError, ValueError) as exc:
        raise LabFileError(f"cannot read the service accounts in {accounts_file}: {exc}") from None
    register_service_accounts(state_dir / "registry.db", accounts)
    return Provisioned(identity, password, created)


def identity_paths(accounts: Iterable[str], directory: Path) -> dict[str, Path]:
    """``wart up``'s layout: STATE/identities/ACCOUNT.key."""
    return {account: directory / f"{account}.key" for account in accounts}
