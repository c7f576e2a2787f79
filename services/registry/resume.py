"""Resume tokens: a browser that logged in before logs in again without a password check.

A password check is an argon2id hash on purpose (~80 ms of a core here), and a class
that reloads its pages at once queued on the registry's two cores for seconds. A
resume token is the registry's Ed25519 signature over a `ResumeGrant` (user, a random
id, an end); checking it costs ~0.1 ms. It is:

- **short-lived**: RESUME_TTL_S (a lab session), never past the session it came from;
- **good once**: a resume uses it up and the new session gets a new one, so a copied
  token is worth one login, and the owner's next resume then says it was used;
- **no more than it says**: a resumed session ends when its token would have, so a
  chain of resumes never outlives the password login it started from;
- **revocable**: its row here is marked revoked by a person's "Log out" (not a page
  closing) in any session of its *chain* (the sessions resumed, one from another,
  since one password login), a kick, a ban, a password change, a logout everywhere
  or the account's removal; the registry alone checks it (it never leaves the
  registry's hands as a session), so no revocation list needs to travel.

The rows live in the registry's database beside the sessions (same file, connection
and lock as accounts_db.py).
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass

import nacl.exceptions

from common.auth import RegistryIdentity
from common.messages import MessageError, ResumeGrant, SignedResume, decode, encode
from common.service import RequestError
from services.registry.accounts_db import RegistryDB

RESUME_TTL_S = 4 * 3600.0
"""How long a resume token is good: an afternoon's lab, far short of a session's 12 h."""

SCHEMA = """
CREATE TABLE IF NOT EXISTS resumes (
    resume_id BLOB PRIMARY KEY,
    user TEXT NOT NULL REFERENCES users(name) ON DELETE CASCADE,
    session_id BLOB NOT NULL,
    issued_at REAL NOT NULL,
    expires_at REAL NOT NULL,
    revoked TEXT
);
CREATE INDEX IF NOT EXISTS resumes_user ON resumes(user);
CREATE INDEX IF NOT EXISTS resumes_session ON resumes(session_id);
CREATE TABLE IF NOT EXISTS resume_chains (
    session_id BLOB PRIMARY KEY,
    chain BLOB NOT NULL,
    expires_at REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS resume_chains_chain ON resume_chains(chain);
"""


def create_table(db: RegistryDB) -> None:
    db.database.create(SCHEMA, "resume table")


def revoke_user(db: RegistryDB, user: str, reason: str) -> int:
    """Every good token of ``user`` revoked (also for `wart users passwd`, registry down)."""
    create_table(db)
    with db._tx() as tx:
        cur = tx.execute(
            "UPDATE resumes SET revoked=? WHERE user=? AND revoked IS NULL", (reason[:200], user)
        )
        return int(cur.rowcount)


AGAIN = "log in with your password"


def _refused(why: str) -> RequestError:
    return RequestError("unauthenticated", f"your saved login {why}: {AGAIN}")


@dataclass(frozen=True)
class Resumed:
    """A token used up by a resume: what it allowed, and the chain its session joins."""

    grant: ResumeGrant
    chain: bytes  # the session id of the password login the chain started from


class ResumeStore:
    """Issues, checks and revokes resume tokens."""

    def __init__(self, db: RegistryDB, identity: RegistryIdentity, realm: str) -> None:
        self.db = db
        self.identity = identity
        self.realm = realm
        create_table(db)

    def issue(self, user: str, session_id: bytes, session_end: float, now: float) -> bytes:
        """A new token for ``user``'s session ``session_id`` (encoded SignedResume)."""
        grant = ResumeGrant(
            realm=self.realm,
            user=user,
            resume_id=secrets.token_bytes(16),
            issued_at=now,
            expires_at=min(now + RESUME_TTL_S, session_end),
        )
        with self.db._tx() as db:
            db.execute(
                "INSERT INTO resumes(resume_id, user, session_id, issued_at, expires_at) "
                "VALUES (?, ?, ?, ?, ?)",
                (grant.resume_id, user, session_id, now, grant.expires_at),
            )
            db.execute("DELETE FROM resumes WHERE expires_at < ?", (now - 60,))
        body = encode(grant)
        signature = self.identity.signing_key.sign(body).signature
        return encode(SignedResume(grant=body, signature=signature))

    def use(self, user: str, token: bytes, now: float) -> Resumed:
        """Check a presented token and use it up; RequestError in words if it is no good."""
        grant = self._check(user, token, now, use_up=True)
        with self.db._tx() as db:
            row = db.execute(
                "SELECT COALESCE(c.chain, r.session_id) FROM resumes r "
                "LEFT JOIN resume_chains c ON c.session_id = r.session_id WHERE r.resume_id=?",
                (grant.resume_id,),
            ).fetchone()
        return Resumed(grant, bytes(row[0]) if row else grant.resume_id)

    def link(self, session_id: bytes, chain: bytes, session_end: float, now: float) -> None:
        """Record that ``session_id`` was resumed within ``chain`` (its logout ends them all)."""
        with self.db._tx() as db:
            db.execute(
                "INSERT OR REPLACE INTO resume_chains(session_id, chain, expires_at) "
                "VALUES (?, ?, ?)",
                (session_id, chain, session_end),
            )
            db.execute("DELETE FROM resume_chains WHERE expires_at < ?", (now - 60,))

    def chain_of(self, session_id: bytes) -> list[bytes]:
        """Every session of ``session_id``'s chain, itself and the password login included."""
        with self.db._tx() as db:
            row = db.execute(
                "SELECT chain FROM resume_chains WHERE session_id=?", (session_id,)
            ).fetchone()
            chain = bytes(row[0]) if row else session_id
            rows = db.execute(
                "SELECT session_id FROM resume_chains WHERE chain=?", (chain,)
            ).fetchall()
        found = [session_id, chain]
        found += [bytes(r[0]) for r in rows]
        return list(dict.fromkeys(found))

    def check(self, user: str, session_id: bytes, token: bytes, now: float) -> None:
        """Is ``token``, the one issued to ``session_id``, still good? Not used up by asking."""
        grant = self._check(user, token, now, use_up=False)
        with self.db._tx() as db:
            row = db.execute(
                "SELECT session_id FROM resumes WHERE resume_id=?", (grant.resume_id,)
            ).fetchone()
        if row is None or bytes(row[0]) != session_id:
            raise _refused("belongs to another session")

    def _check(self, user: str, token: bytes, now: float, *, use_up: bool) -> ResumeGrant:
        try:
            signed = decode(token, SignedResume)
            self.identity.signing_key.verify_key.verify(signed.grant, signed.signature)
            grant = decode(signed.grant, ResumeGrant)
        except (MessageError, nacl.exceptions.BadSignatureError, nacl.exceptions.ValueError):
            raise _refused("is not one this lab's registry signed") from None
        if grant.realm != self.realm or grant.user != user:
            raise _refused(f"is for another account or lab (it names {grant.user})")
        if now >= grant.expires_at:
            raise _refused(f"expired {_ago(now - grant.expires_at)} ago")
        with self.db._tx() as db:
            row = db.execute(
                "SELECT revoked FROM resumes WHERE resume_id=? AND user=?",
                (grant.resume_id, user),
            ).fetchone()
            if row is None:
                raise _refused("is not known here any more")
            if row[0] is not None:
                raise _refused(f"was revoked ({row[0]})")
            if not use_up:
                return grant
            db.execute(
                "UPDATE resumes SET revoked='used: a resume gives a new one' WHERE resume_id=?",
                (grant.resume_id,),
            )
        return grant

    def revoke_sessions(self, session_ids: list[bytes], reason: str) -> None:
        """The tokens of these sessions (their logout, a kick) are no good any more."""
        with self.db._tx() as db:
            db.executemany(
                "UPDATE resumes SET revoked=? WHERE session_id=? AND revoked IS NULL",
                [(reason[:200], sid) for sid in session_ids],
            )

    def revoke_user(self, user: str, reason: str) -> int:
        """Every token of ``user`` (a kick, a ban, a password change); how many were good."""
        return revoke_user(self.db, user, reason)


def _ago(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


__all__ = ["RESUME_TTL_S", "ResumeStore", "Resumed", "revoke_user"]
