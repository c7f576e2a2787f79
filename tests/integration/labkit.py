"""A small lab for integration tests: a registry and chat rooms as real processes."""

from __future__ import annotations

import functools
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import zenoh

from common import keys
from common.auth import RegistryIdentity, create_identity_key
from common.client.lab_client import LabClient
from common.keys import AliveKind
from common.service import close_session, open_session
from services.lab.supervisor import AliveWatch
from services.registry import accounts_db
from services.registry.accounts_db import RegistryDB, hash_password
from tests.conftest import Proc, Procs, Router

PASSWORD = "correct horse"
USERS = {"alice": "student", "bob": "student", "carol": "student", "ida": "instructor"}


@dataclass
class Lab:
    router: Router
    procs: Procs
    state: Path
    identity: RegistryIdentity
    registry: Proc | None = None

    @property
    def db_path(self) -> Path:
        return self.state / "registry.db"

    @property
    def key_hex(self) -> str:
        return self.identity.verify_key.hex()

    def net_args(self) -> list[str]:
        return [*self.router.net_args(), "--registry-key", self.key_hex]

    def start_registry(self) -> Proc:
        self.registry = self.procs.start(
            "registry",
            [
                "registry",
                "--db",
                str(self.db_path),
                "--key-file",
                str(self.state / "registry.key"),
                *self.net_args(),
            ],
        )
        self.wait_alive(AliveKind.REGISTRY, "registry", self.registry)
        return self.registry

    def start_room(self, room: str, *extra: str) -> Proc:
        account = f"chat-{room}"
        key_file = self.state / f"{account}.key"
        if not key_file.exists():
            key = create_identity_key(key_file)
            db = RegistryDB(self.db_path)
            db.add_user(account, ["service"], public_key=bytes(key.verify_key))
            db.close()
        proc = self.procs.start(
            f"room-{room}",
            [
                "context",
                "chat",
                "--name",
                room,
                "--user",
                account,
                "--identity",
                str(key_file),
                "--data-dir",
                str(self.state / "rooms"),
                *extra,
                *self.net_args(),
            ],
        )
        self.wait_alive(AliveKind.CONTEXT, room, proc)
        return proc

    def wait_alive(self, kind: AliveKind, ident: str, proc: Proc) -> None:
        session = open_session(self.router.options(), wait=10.0)
        try:
            watch = AliveWatch(session, keys.alive(self.router.realm, kind, ident))
            ok = watch.wait(
                keys.alive(self.router.realm, kind, ident),
                30.0,
                lambda: proc.popen.poll() is not None,
            )
            watch.close()
        finally:
            close_session(session)
        assert ok, f"{ident} did not come up:\n{proc.output()}"

    @contextmanager
    def client(self, user: str | None = None, password: str = PASSWORD) -> Iterator[LabClient]:
        session = open_session(self.router.options(), wait=10.0)
        try:
            with LabClient(session, self.router.realm, self.identity.verify_key) as client:
                if user is not None:
                    client.login(user, password)
                yield client
        finally:
            close_session(session)

    def zsession(self) -> zenoh.Session:
        return open_session(self.router.options(), wait=10.0)


@functools.cache
def _password_hash(password: str) -> bytes:
    """One argon2id hash of ``password`` per test session (about 0.2 s each on a busy machine).

    A salted hash string verifies whichever account holds it, so every lab's
    accounts can share it; make_lab otherwise hashed six passwords per test.
    """
    return hash_password(password)


def make_lab(router: Router, procs: Procs, tmp: Path, *, users: dict[str, str] = USERS) -> Lab:
    state = tmp / "state"
    state.mkdir()
    identity, _ = RegistryIdentity.load_or_create(state / "registry.key")
    db = RegistryDB(state / "registry.db")
    with mock.patch.object(accounts_db, "hash_password", _password_hash):
        # the admin ensure_admin would make, with PASSWORD rather than a random one
        db.add_user("admin", ["admin"], password=PASSWORD)
        for name, role in users.items():
            db.add_user(name, [role], password=PASSWORD)
    db.close()
    return Lab(router=router, procs=procs, state=state, identity=identity)
