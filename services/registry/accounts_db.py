"""The registry's SQLite database: accounts, credentials, grants, sessions, mailboxes.

One file (WAL journal), created on first open. Used by the registry process
and by ``wart users`` (which may run while the registry is up: WAL lets both
read and write). Every value read back is checked (names, grants, scopes), so
a hand-edited or damaged row is skipped with a warning, never trusted.

Credential kinds are pluggable (thesis 5.5): a row in ``credentials`` names its
kind and holds that kind's data; :data:`CHECKS` maps a kind to the function
that checks a presented credential against it.
"""

from __future__ import annotations

import functools
import logging
import secrets
import sqlite3
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path

import nacl.exceptions
import nacl.pwhash

from common import acl
from common.auth import RegistryIdentity
from common.keys import check_ident, is_ident
from services.lab.database import DbError, LabDatabase

log = logging.getLogger("wart.registry.db")

SCHEMA = """
CREATE TABLE IF NOT EXISTS users (
    name TEXT PRIMARY KEY,
    created_at REAL NOT NULL,
    mailbox_key BLOB
);
CREATE TABLE IF NOT EXISTS credentials (
    user TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    kind TEXT NOT NULL,
    data BLOB NOT NULL,
    PRIMARY KEY (user, kind, data)
);
CREATE TABLE IF NOT EXISTS grants (
    user TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    scope TEXT NOT NULL,
    grant_name TEXT NOT NULL,
    PRIMARY KEY (user, scope, grant_name)
);
CREATE TABLE IF NOT EXISTS sessions (
    session_id BLOB PRIMARY KEY,
    user TEXT NOT NULL,
    box_key BLOB NOT NULL,
    issued_at REAL NOT NULL,
    expires_at REAL NOT NULL,
    revoked_at REAL,
    reason TEXT,
    kicked INTEGER NOT NULL DEFAULT 0
);
CREATE INDEX IF NOT EXISTS sessions_user ON sessions(user);
CREATE TABLE IF NOT EXISTS mailbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    recipient TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    stored_at REAL NOT NULL,
    payload BLOB NOT NULL
);
CREATE TABLE IF NOT EXISTS settings (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""

MAILBOX_LIMIT = 200
"""Private messages kept per offline user; the oldest go first."""

# argon2id at libsodium's "interactive" cost: about 50 ms and 64 MiB per check here.
OPSLIMIT = nacl.pwhash.argon2id.OPSLIMIT_INTERACTIVE
MEMLIMIT = nacl.pwhash.argon2id.MEMLIMIT_INTERACTIVE
MIN_PASSWORD = 8
RESERVED_NAMES = frozenset({"registry", "local", "unknown"})
"""The registry's own session, and who the audit trail names for the database file's
tools and for what does not verify: never an account's name."""


def hash_password(password: str) -> bytes:
    if len(password) < MIN_PASSWORD:
        raise DbError("bad_request", f"a password needs at least {MIN_PASSWORD} characters")
    return nacl.pwhash.argon2id.str(password.encode(), opslimit=OPSLIMIT, memlimit=MEMLIMIT)


def _check_password(stored: bytes, presented: object) -> bool:
    if not isinstance(presented, str):
        return False
    try:
        return bool(nacl.pwhash.verify(stored, presented.encode()))
    except (nacl.exceptions.InvalidkeyError, nacl.exceptions.CryptoError):
        return False


def _check_ed25519(stored: bytes, presented: object) -> bool:
    return isinstance(presented, bytes) and secrets.compare_digest(stored, presented)


CHECKS: dict[str, Callable[[bytes, object], bool]] = {
    "password": _check_password,  # data: the argon2id hash string
    "ed25519": _check_ed25519,  # data: the 32-byte public key (the signature is checked first)
}


@functools.cache
def _dummy_hash() -> bytes:
    """A hash to check against when the user does not exist, so timing does not tell (made on
    first use: every process importing this module would otherwise pay one argon2id)."""
    return nacl.pwhash.argon2id.str(b"not a password", opslimit=OPSLIMIT, memlimit=MEMLIMIT)


@dataclass(frozen=True)
class UserRecord:
    name: str
    grants: tuple[tuple[str, str], ...]  # (scope, grant)
    credential_kinds: tuple[str, ...]


@dataclass(frozen=True)
class SessionRecord:
    session_id: bytes
    user: str
    box_key: bytes
    expires_at: float
    revoked_at: float | None
    reason: str
    kicked: bool


class RegistryDB:
    """Thread-safe access to the registry database."""

    def __init__(self, path: Path) -> None:
        self.database = LabDatabase(path)
        self.path = path
        self.created = self.database.created
        self.database.create(SCHEMA, "account tables")

    def close(self) -> None:
        self.database.close()

    def _tx(self) -> AbstractContextManager[sqlite3.Connection]:
        return self.database.transaction()

    def _rows(self, sql: str, *args: object) -> list[tuple]:
        return self.database.rows(sql, *args)

    # -- settings

    def setting(self, key: str, default: str) -> str:
        rows = self._rows("SELECT value FROM settings WHERE key=?", key)
        return str(rows[0][0]) if rows else default

    def set_setting(self, key: str, value: str) -> None:
        with self._tx() as db:
            db.execute("INSERT OR REPLACE INTO settings(key, value) VALUES (?, ?)", (key, value))

    # -- accounts

    def user_exists(self, name: str) -> bool:
        return bool(self._rows("SELECT 1 FROM users WHERE name=?", name))

    def add_user(
        self,
        name: str,
        roles: list[str] | tuple[str, ...] = ("student",),
        *,
        password: str | None = None,
        public_key: bytes | None = None,
    ) -> None:
        try:
            check_ident("user", name)
        except ValueError as exc:
            raise DbError("bad_request", str(exc)) from None
        if name.lower() in RESERVED_NAMES:
            raise DbError("conflict", f"the name {name} is reserved")
        for role in roles:
            self._valid_grant(acl.ROLE_PREFIX + role, "")
        hashed = hash_password(password) if password is not None else None
        if public_key is not None and len(public_key) != 32:
            raise DbError("bad_request", "an Ed25519 public key has 32 bytes")
        with self._tx() as db:
            if db.execute("SELECT 1 FROM users WHERE name=?", (name,)).fetchone():
                raise DbError("conflict", f"user {name} already exists")
            # alice and ALICE would be two accounts one person cannot tell apart.
            same = db.execute("SELECT name FROM users WHERE lower(name)=lower(?)", (name,))
            if (other := same.fetchone()) is not None:
                raise DbError("conflict", f"user {other[0]} already exists (the same but for case)")
            db.execute("INSERT INTO users(name, created_at) VALUES (?, ?)", (name, time.time()))
            for role in roles:
                db.execute(
                    "INSERT INTO grants(user, scope, grant_name) VALUES (?, '', ?)",
                    (name, acl.ROLE_PREFIX + role),
                )
            if hashed is not None:
                db.execute(
                    "INSERT INTO credentials(user, kind, data) VALUES (?, 'password', ?)",
                    (name, hashed),
                )
            if public_key is not None:
                db.execute(
                    "INSERT INTO credentials(user, kind, data) VALUES (?, 'ed25519', ?)",
                    (name, public_key),
                )

    def _require_user(self, db: sqlite3.Connection, name: str) -> None:
        if not db.execute("SELECT 1 FROM users WHERE name=?", (name,)).fetchone():
            raise DbError("not_found", f"no user named {name}")

    def set_password(self, name: str, password: str) -> None:
        """Replace the password; the mailbox key derived from the old one is forgotten."""
        hashed = hash_password(password)
        with self._tx() as db:
            self._require_user(db, name)
            db.execute("DELETE FROM credentials WHERE user=? AND kind='password'", (name,))
            db.execute(
                "INSERT INTO credentials(user, kind, data) VALUES (?, 'password', ?)",
                (name, hashed),
            )

    def add_key(self, name: str, public_key: bytes) -> None:
        if len(public_key) != 32:
            raise DbError("bad_request", "an Ed25519 public key has 32 bytes")
        with self._tx() as db:
            self._require_user(db, name)
            db.execute(
                "INSERT OR IGNORE INTO credentials(user, kind, data) VALUES (?, 'ed25519', ?)",
                (name, public_key),
            )

    def remove_user(self, name: str) -> None:
        with self._tx() as db:
            self._require_user(db, name)
            db.execute("DELETE FROM users WHERE name=?", (name,))

    def users(self) -> list[UserRecord]:
        names = [r[0] for r in self._rows("SELECT name FROM users ORDER BY name")]
        out = []
        for name in names:
            if not is_ident(name):
                log.warning("skipping a user with an invalid name in the database: %r", name)
                continue
            out.append(self.user(name))
        return out

    def user(self, name: str) -> UserRecord:
        if not self.user_exists(name):
            raise DbError("not_found", f"no user named {name}")
        kinds = self._rows("SELECT DISTINCT kind FROM credentials WHERE user=? ORDER BY kind", name)
        return UserRecord(
            name=name,
            grants=tuple(self.grants_of(name)),
            credential_kinds=tuple(str(k[0]) for k in kinds),
        )

    def admins(self) -> list[str]:
        rows = self._rows(
            "SELECT DISTINCT user FROM grants "
            "WHERE scope='' AND grant_name IN ('admin', 'role:admin')"
        )
        return [str(r[0]) for r in rows]

    # -- grants

    def _valid_grant(self, grant: str, scope: str) -> None:
        try:
            acl.check_grant(grant)
            acl.check_scope(scope)
        except acl.AclError as exc:
            raise DbError("bad_request", str(exc)) from None

    def grant(self, name: str, grant: str, scope: str = "") -> None:
        self._valid_grant(grant, scope)
        with self._tx() as db:
            self._require_user(db, name)
            db.execute(
                "INSERT OR IGNORE INTO grants(user, scope, grant_name) VALUES (?, ?, ?)",
                (name, scope, grant),
            )

    def ungrant(self, name: str, grant: str, scope: str = "") -> None:
        with self._tx() as db:
            self._require_user(db, name)
            cur = db.execute(
                "DELETE FROM grants WHERE user=? AND scope=? AND grant_name=?", (name, scope, grant)
            )
            if cur.rowcount == 0:
                where = f" in {scope}" if scope else ""
                raise DbError("not_found", f"user {name} has no grant {grant}{where}")

    def grants_of(self, name: str) -> list[tuple[str, str]]:
        out = []
        for scope, grant in self._rows(
            "SELECT scope, grant_name FROM grants WHERE user=? ORDER BY scope, grant_name", name
        ):
            try:
                acl.check_scope(scope)
                acl.check_grant(grant)
            except (acl.AclError, TypeError, AttributeError):
                log.warning(
                    "ignoring a malformed grant of %s in the database: %r %r", name, scope, grant
                )
                continue
            out.append((str(scope), str(grant)))
        return out

    # -- credentials

    def check_credential(self, name: str, kind: str, presented: object) -> bool:
        """Whether ``presented`` matches one of the user's credentials of ``kind``."""
        check = CHECKS.get(kind)
        if check is None:
            return False
        rows = self._rows("SELECT data FROM credentials WHERE user=? AND kind=?", name, kind)
        if not rows and kind == "password":
            _check_password(_dummy_hash(), presented)  # same cost as a real check
            return False
        return any(isinstance(r[0], bytes) and check(r[0], presented) for r in rows)

    def ensure_admin(self, name: str = "admin") -> str | None:
        """Create an admin account with a random password if there is no admin; return it."""
        if self.admins():
            return None
        password = secrets.token_urlsafe(12)
        if self.user_exists(name):
            self.set_password(name, password)
            self.grant(name, "role:admin")
        else:
            self.add_user(name, ["admin"], password=password)
        return password

    # -- sessions and revocations

    def record_session(
        self, session_id: bytes, user: str, box_key: bytes, issued_at: float, expires_at: float
    ) -> None:
        with self._tx() as db:
            db.execute(
                "INSERT INTO sessions(session_id, user, box_key, issued_at, expires_at) "
                "VALUES (?, ?, ?, ?, ?)",
                (session_id, user, box_key, issued_at, expires_at),
            )
            # Sessions past expiry need no revocation any more.
            db.execute("DELETE FROM sessions WHERE expires_at < ?", (time.time() - 60,))

    def session(self, session_id: bytes) -> SessionRecord | None:
        rows = self._rows(
            "SELECT session_id, user, box_key, expires_at, revoked_at, reason, kicked "
            "FROM sessions WHERE session_id=?",
            session_id,
        )
        return _session(rows[0]) if rows else None

    def revoke(
        self, session_id: bytes, reason: str, *, kicked: bool = False
    ) -> SessionRecord | None:
        """The session, revoked now; None if unknown or revoked before."""
        with self._tx() as db:
            cur = db.execute(
                "UPDATE sessions SET revoked_at=?, reason=?, kicked=? "
                "WHERE session_id=? AND revoked_at IS NULL",
                (time.time(), reason, int(kicked), session_id),
            )
        return self.session(session_id) if cur.rowcount else None

    def active_sessions(self, user: str, now: float | None = None) -> list[SessionRecord]:
        now = time.time() if now is None else now
        rows = self._rows(
            "SELECT session_id, user, box_key, expires_at, revoked_at, reason, kicked "
            "FROM sessions WHERE user=? AND revoked_at IS NULL AND expires_at > ?",
            user,
            now,
        )
        return [_session(r) for r in rows]

    def revocations(self, now: float | None = None) -> list[SessionRecord]:
        """Revoked sessions whose tokens have not expired yet."""
        now = time.time() if now is None else now
        rows = self._rows(
            "SELECT session_id, user, box_key, expires_at, revoked_at, reason, kicked "
            "FROM sessions WHERE revoked_at IS NOT NULL AND expires_at > ?",
            now,
        )
        return [_session(r) for r in rows]

    # -- mailboxes

    def set_mailbox_key(self, user: str, key: bytes) -> None:
        """Record the user's mailbox key; a new key makes kept messages unreadable: drop them."""
        with self._tx() as db:
            row = db.execute("SELECT mailbox_key FROM users WHERE name=?", (user,)).fetchone()
            if row is None or row[0] == key:
                return
            db.execute("UPDATE users SET mailbox_key=? WHERE name=?", (key, user))
            if row[0] is not None:
                db.execute("DELETE FROM mailbox WHERE recipient=?", (user,))

    def mailbox_key(self, user: str) -> bytes | None:
        rows = self._rows("SELECT mailbox_key FROM users WHERE name=?", user)
        key = rows[0][0] if rows else None
        return key if isinstance(key, bytes) and len(key) == 32 else None

    def deposit(self, recipient: str, payload: bytes) -> None:
        with self._tx() as db:
            self._require_user(db, recipient)
            db.execute(
                "INSERT INTO mailbox(recipient, stored_at, payload) VALUES (?, ?, ?)",
                (recipient, time.time(), payload),
            )
            db.execute(
                "DELETE FROM mailbox WHERE recipient=? AND id NOT IN "
                "(SELECT id FROM mailbox WHERE recipient=? ORDER BY id DESC LIMIT ?)",
                (recipient, recipient, MAILBOX_LIMIT),
            )

    def take_mailbox(self, recipient: str) -> list[bytes]:
        with self._tx() as db:
            rows = db.execute(
                "SELECT payload FROM mailbox WHERE recipient=? ORDER BY id", (recipient,)
            ).fetchall()
            db.execute("DELETE FROM mailbox WHERE recipient=?", (recipient,))
        return [r[0] for r in rows if isinstance(r[0], bytes)]


def _session(row: tuple) -> SessionRecord:
    session_id, user, box_key, expires_at, revoked_at, reason, kicked = row
    return SessionRecord(
        session_id=bytes(session_id),
        user=str(user),
        box_key=bytes(box_key),
        expires_at=float(expires_at),
        revoked_at=None if revoked_at is None else float(revoked_at),
        reason=str(reason or ""),
        kicked=bool(kicked),
    )


def provision(db_path: Path, key_path: Path) -> tuple[RegistryIdentity, str | None, bool]:
    """Create the key and the database if needed; (identity, new admin password, key created)."""
    identity, created = RegistryIdentity.load_or_create(key_path)
    db = RegistryDB(db_path)
    try:
        password = db.ensure_admin()
    finally:
        db.close()
    if password is not None:
        secret = db_path.parent / "admin-password.txt"
        secret.write_text(f"{password}\n")
        secret.chmod(0o600)
    return identity, password, created
