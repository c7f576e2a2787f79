"""Authentication of every client-to-service message.

Trust is anchored in one key: the registry's Ed25519 key, pinned in each
realm's configuration. The registry signs a :class:`SessionToken` at login;
the token names the session's own Ed25519 key. The client then signs each
message with that session key inside an :class:`AuthEnvelope`. A service
checks, before the message has any effect:

1. the token's signature against the pinned registry key (cached per token),
2. the token's realm, expiry and revocation,
3. the envelope's signature by the session key, over the key expression too,
4. freshness: ``sent_at`` within a window of the service's clock, and a
   sequence number not seen before from that session (replay),
5. the permission, through :meth:`Principal.require` or a policy of the caller.

The registry's X25519 box key is derived from its Ed25519 key, so pinning one
key pins both.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar, overload

import nacl.exceptions
import nacl.public
import nacl.signing

from common.messages.auth import AuthEnvelope, SessionToken, SignedToken
from common.messages.base import ErrorCode, Expected, Message, MessageError, decode, encode
from common.messages.registry import ResumeGrant, SignedResume

M = TypeVar("M", bound=Message)
# The other members of a tuple of expected types (open's overloads, as decode's).
M2 = TypeVar("M2", bound=Message)
M3 = TypeVar("M3", bound=Message)
M4 = TypeVar("M4", bound=Message)

DEFAULT_FRESHNESS_WINDOW = 30.0
"""Seconds a message may be older (or newer, for clock skew) than the service's clock."""

REPLAY_WINDOW = 1024
"""How far out of order a session's messages may arrive and still be accepted."""

LOGIN_WAIT_S = 30.0
"""How long a login waits for the registry's answer.

Password checks are slow on purpose (argon2id, ~65 ms of a core each), so when a
class logs in at one instant they queue at the registry: 100 at once on 2 cores
is ~3.3 s, several times that on a busy host. A login is answered late rather
than given up after the usual request timeout. A registry that is not running
costs nothing extra: with no queryable to route to, the router ends the query at once.
"""

LOGIN_STALE_S = 27.0
"""How long a login may wait at the registry for a password-check worker before the
registry answers "busy: try again" instead of checking it: shorter than LOGIN_WAIT_S
by a check's time, so a swamped registry's answer reaches an asker who still listens
(at 20 s, a class of 50 logging in at load 27 had four students told "busy" whose
checks would have been answered in time)."""

LOGIN_FIND_S = 2.0
"""How long a login keeps asking while no registry is routed to (the query ends at once).

A registry that has just (re)started is announced to each session separately:
a login sent in the same instant it came back was told "no registry answered"
(a fresh-clone run, 2026-11-25), although the registry's liveliness token was
already seen elsewhere. A login asks again every LOGIN_FIND_PAUSE_S for this
long before saying so; a registry that is really down is said 2 s later.
"""

LOGIN_FIND_PAUSE_S = 0.25


class AuthError(Exception):
    """A message was refused; ``code`` is the ErrorReply code to answer with."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code: ErrorCode = code
        self.message = message


def key_fingerprint(verify_key: bytes) -> str:
    """A short human-comparable fingerprint of a public key (as SSH prints them)."""
    digest = hashlib.blake2b(verify_key, digest_size=16).hexdigest()
    return ":".join(digest[i : i + 4] for i in range(0, 32, 4))


def parse_public_key(text: str) -> bytes:
    """A 32-byte public key from its 64-character hex form, with a clear error."""
    text = text.strip()
    try:
        raw = bytes.fromhex(text)
    except ValueError:
        raise ValueError(f"not a hex public key: {text[:16]!r}...") from None
    if len(raw) != 32:
        raise ValueError(f"a public key has 32 bytes (64 hex digits), this one has {len(raw)}")
    return raw


# --- the registry's identity ----------------------------------------------------


@dataclass(frozen=True)
class RegistryIdentity:
    """The registry's signing key; its public half is what every service pins."""

    signing_key: nacl.signing.SigningKey

    @classmethod
    def generate(cls) -> RegistryIdentity:
        return cls(nacl.signing.SigningKey.generate())

    @classmethod
    def load_or_create(cls, path: Path) -> tuple[RegistryIdentity, bool]:
        """Load the key file, or create it (mode 0600). Returns (identity, created).

        The file holds the 32-byte seed, or the same as 64 hex digits (a key handed
        over as text: a Kubernetes Secret's stringData, podman's secrets).
        """
        if path.exists():
            seed = path.read_bytes()
            if len(seed.strip()) == 64:
                # not hex (64 raw bytes): refused as damaged below
                with contextlib.suppress(UnicodeDecodeError, ValueError):
                    seed = bytes.fromhex(seed.strip().decode("ascii"))
            if len(seed) != 32:
                raise ValueError(f"registry key file {path} is damaged ({len(seed)} bytes, not 32)")
            return cls(nacl.signing.SigningKey(seed)), False
        path.parent.mkdir(parents=True, exist_ok=True)
        identity = cls.generate()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as out:
            out.write(bytes(identity.signing_key))
        return identity, True

    @property
    def verify_key(self) -> bytes:
        return bytes(self.signing_key.verify_key)

    @property
    def box_private_key(self) -> nacl.public.PrivateKey:
        return self.signing_key.to_curve25519_private_key()

    def sign_token(self, token: SessionToken) -> SignedToken:
        body = encode(token)
        return SignedToken(token=body, signature=self.signing_key.sign(body).signature)


def load_identity_key(path: Path) -> nacl.signing.SigningKey:
    """An Ed25519 identity key (service accounts, scripts) from a file, with a clear error.

    The file holds the 32-byte seed, raw or as 64 hex digits (``wart users keygen``).
    """
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"cannot read identity key {path}: {exc.strerror}") from None
    if len(raw) != 32:
        try:
            raw = bytes.fromhex(raw.decode("ascii").strip())
        except (UnicodeDecodeError, ValueError):
            raw = b""
    if len(raw) != 32:
        raise ValueError(f"identity key file {path} is not a 32-byte Ed25519 seed (raw or hex)")
    return nacl.signing.SigningKey(raw)


def create_identity_key(path: Path) -> nacl.signing.SigningKey:
    """Create an identity key file (hex seed, mode 0600); refuses to overwrite one."""
    key = nacl.signing.SigningKey.generate()
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as out:
        out.write(bytes(key).hex() + "\n")
    return key


def registry_box_key(registry_verify_key: bytes) -> nacl.public.PublicKey:
    """The registry's X25519 key that login credentials are sealed to."""
    return nacl.signing.VerifyKey(registry_verify_key).to_curve25519_public_key()


# --- the client side -------------------------------------------------------------


def _signed_bytes(key_expr: str, seq: int, sent_at: float, body: bytes) -> bytes:
    key = key_expr.encode()
    return struct.pack("<I", len(key)) + key + struct.pack("<Qd", seq, sent_at) + body


@dataclass
class SessionKeys:
    """The private halves of a session, created by the client before it logs in."""

    signing_key: nacl.signing.SigningKey = field(default_factory=nacl.signing.SigningKey.generate)
    box_key: nacl.public.PrivateKey = field(default_factory=nacl.public.PrivateKey.generate)

    @property
    def session_public_key(self) -> bytes:
        return bytes(self.signing_key.verify_key)

    @property
    def box_public_key(self) -> bytes:
        return bytes(self.box_key.public_key)


class Session:
    """A logged-in session: its keys and the registry-signed token. Thread-safe."""

    def __init__(self, keys: SessionKeys, signed_token: SignedToken, token: SessionToken) -> None:
        if token.session_key != keys.session_public_key:
            raise AuthError("unauthenticated", "the token does not belong to these session keys")
        self.keys = keys
        self.signed_token = signed_token
        self.token = token
        self._seq = 0
        self._lock = threading.Lock()

    @property
    def user(self) -> str:
        return self.token.user

    @property
    def session_id(self) -> bytes:
        return self.token.session_id

    def has(self, permission: str) -> bool:
        return permission in self.token.permissions

    def next_seq(self) -> int:
        """The session's next sequence number (envelopes and MAC commands share the counter)."""
        with self._lock:
            self._seq += 1
            return self._seq

    def seal(self, key_expr: str, message: Message, *, now: float | None = None) -> bytes:
        """The encoded AuthEnvelope carrying ``message`` to ``key_expr``."""
        body = encode(message)
        seq = self.next_seq()
        sent_at = time.time() if now is None else now
        signature = self.keys.signing_key.sign(
            _signed_bytes(key_expr, seq, sent_at, body)
        ).signature
        return encode(
            AuthEnvelope(
                token=self.signed_token, seq=seq, sent_at=sent_at, body=body, signature=signature
            )
        )


# --- the service side -------------------------------------------------------------


@dataclass(frozen=True)
class Principal:
    """The verified sender of a message."""

    user: str
    session_id: bytes
    permissions: frozenset[str]
    roles: tuple[str, ...]
    token: SessionToken

    def has(self, permission: str) -> bool:
        return permission in self.permissions

    def allowed(
        self, permission: str, scope: str | None = None, *, restricted: bool = False
    ) -> bool:
        """Whether ``permission`` holds in ``scope`` ("ctx/<ctx>", "agent/<ctx>/<agent>").

        Global grants hold everywhere unless ``restricted``; see common.acl.allowed.
        """
        from common.acl import allowed  # common.acl imports nothing from here; avoids a cycle

        return allowed(
            permission, self.permissions, self.token.grants, scope, restricted=restricted
        )

    def require(
        self, permission: str, what: str = "", *, scope: str | None = None, restricted: bool = False
    ) -> None:
        if not self.allowed(permission, scope, restricted=restricted):
            action = f" to {what}" if what else ""
            where = f" in {scope}" if scope else ""
            raise AuthError(
                "forbidden",
                f"user {self.user} does not have the '{permission}' permission{where}{action}",
            )


class ReplayWindow:
    """Accepts each sequence number once, within REPLAY_WINDOW of the newest seen."""

    __slots__ = ("expires_at", "highest", "seen")

    def __init__(self, expires_at: float) -> None:
        self.highest = 0
        self.seen = 0  # bit i set: highest - i was seen
        self.expires_at = expires_at

    def accept(self, seq: int) -> bool:
        if seq > self.highest:
            shift = seq - self.highest
            # A jump past the window forgets everything; shifting by it would build a huge int.
            if shift >= REPLAY_WINDOW:
                self.seen = 1
            else:
                self.seen = ((self.seen << shift) | 1) & ((1 << REPLAY_WINDOW) - 1)
            self.highest = seq
            return True
        offset = self.highest - seq
        if offset >= REPLAY_WINDOW or (self.seen >> offset) & 1:
            return False
        self.seen |= 1 << offset
        return True


class Verifier:
    """Checks AuthEnvelopes for one service. Thread-safe.

    ``clock`` is injectable so tests can move time; revocations come from the
    registry (its revocation stream and its list at start-up).
    """

    def __init__(
        self,
        registry_verify_key: bytes,
        realm: str,
        *,
        window: float = DEFAULT_FRESHNESS_WINDOW,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self._registry_key = nacl.signing.VerifyKey(registry_verify_key)
        self.realm = realm
        self.window = window
        self.clock = clock
        self._lock = threading.Lock()
        # Verified tokens, keyed by exactly what was verified (bytes and signature).
        self._tokens: dict[tuple[bytes, bytes], SessionToken] = {}
        self._replay: dict[bytes, ReplayWindow] = {}  # by session id
        self._revoked: dict[bytes, float] = {}  # session id -> token expiry
        self.rejected = 0

    # -- revocation

    def revoke(self, session_id: bytes, expires_at: float | None = None) -> None:
        with self._lock:
            self._revoked[session_id] = expires_at if expires_at is not None else float("inf")

    def revoke_many(self, sessions: Iterable[tuple[bytes, float]]) -> None:
        for session_id, expires_at in sessions:
            self.revoke(session_id, expires_at)

    @property
    def registry_key(self) -> bytes:
        """The registry's verify key this verifier trusts (its revocations are signed by it)."""
        return bytes(self._registry_key)

    def is_revoked(self, session_id: bytes) -> bool:
        with self._lock:
            return session_id in self._revoked

    # -- tokens

    def verify_token(self, signed: SignedToken) -> SessionToken:
        """The token, if the registry signed it for this realm and it is in force."""
        with self._lock:
            token = self._tokens.get((signed.token, signed.signature))
        if token is None:
            try:
                self._registry_key.verify(signed.token, signed.signature)
            except nacl.exceptions.BadSignatureError:
                raise AuthError(
                    "unauthenticated", "session token not signed by this lab's registry"
                ) from None
            try:
                token = decode(signed.token, SessionToken)
            except MessageError as exc:
                raise AuthError("unauthenticated", f"unreadable session token: {exc}") from None
            if token.realm != self.realm:
                raise AuthError(
                    "unauthenticated",
                    f"session token is for realm {token.realm}, not {self.realm}",
                )
            with self._lock:
                if len(self._tokens) > 10_000:
                    self._prune_locked()
                self._tokens[(signed.token, signed.signature)] = token
        now = self.clock()
        if now > token.expires_at:
            raise AuthError("unauthenticated", f"session of {token.user} has expired: log in again")
        if self.is_revoked(token.session_id):
            raise AuthError("unauthenticated", f"session of {token.user} was revoked")
        return token

    def principal(self, token: SessionToken) -> Principal:
        return Principal(
            user=token.user,
            session_id=token.session_id,
            permissions=frozenset(token.permissions),
            roles=tuple(token.roles),
            token=token,
        )

    # -- envelopes

    # Overloads per tuple length, as decode's: a body of (A, B) is typed A | B.
    @overload
    def open(self, key_expr: str, payload: object, expected: type[M]) -> tuple[Principal, M]: ...
    @overload
    def open(
        self, key_expr: str, payload: object, expected: tuple[type[M], type[M2]]
    ) -> tuple[Principal, M | M2]: ...
    @overload
    def open(
        self, key_expr: str, payload: object, expected: tuple[type[M], type[M2], type[M3]]
    ) -> tuple[Principal, M | M2 | M3]: ...
    @overload
    def open(
        self,
        key_expr: str,
        payload: object,
        expected: tuple[type[M], type[M2], type[M3], type[M4]],
    ) -> tuple[Principal, M | M2 | M3 | M4]: ...
    @overload
    def open(
        self, key_expr: str, payload: object, expected: tuple[type[Message], ...]
    ) -> tuple[Principal, Message]: ...
    def open(self, key_expr: str, payload: object, expected: Expected) -> tuple[Principal, Message]:
        """Verify an AuthEnvelope received on ``key_expr`` and decode its body.

        Raises AuthError ("unauthenticated") for anything not from a valid,
        fresh session, and MessageError for a body that is not ``expected``.
        """
        try:
            envelope = decode(payload, AuthEnvelope)
        except MessageError as exc:
            self.rejected += 1
            raise AuthError("unauthenticated", f"not an authenticated message ({exc})") from None
        return self.open_envelope(key_expr, envelope, expected)

    @overload
    def open_envelope(
        self, key_expr: str, envelope: AuthEnvelope, expected: type[M]
    ) -> tuple[Principal, M]: ...
    @overload
    def open_envelope(
        self, key_expr: str, envelope: AuthEnvelope, expected: tuple[type[M], type[M2]]
    ) -> tuple[Principal, M | M2]: ...
    @overload
    def open_envelope(
        self, key_expr: str, envelope: AuthEnvelope, expected: tuple[type[M], type[M2], type[M3]]
    ) -> tuple[Principal, M | M2 | M3]: ...
    @overload
    def open_envelope(
        self,
        key_expr: str,
        envelope: AuthEnvelope,
        expected: tuple[type[M], type[M2], type[M3], type[M4]],
    ) -> tuple[Principal, M | M2 | M3 | M4]: ...
    @overload
    def open_envelope(
        self, key_expr: str, envelope: AuthEnvelope, expected: tuple[type[Message], ...]
    ) -> tuple[Principal, Message]: ...
    def open_envelope(
        self, key_expr: str, envelope: AuthEnvelope, expected: Expected
    ) -> tuple[Principal, Message]:
        """:meth:`open` for an envelope already decoded (a caller that accepts several kinds)."""
        try:
            token = self.verify_token(envelope.token)
            now = self.clock()
            if abs(now - envelope.sent_at) > self.window:
                raise AuthError(
                    "unauthenticated",
                    f"message is {now - envelope.sent_at:+.1f} s off this service's clock "
                    f"(allowed ±{self.window:.0f} s): check the clocks, or it is a replay",
                )
            session_key = nacl.signing.VerifyKey(token.session_key)
            try:
                session_key.verify(
                    _signed_bytes(key_expr, envelope.seq, envelope.sent_at, envelope.body),
                    envelope.signature,
                )
            except nacl.exceptions.BadSignatureError:
                raise AuthError(
                    "unauthenticated", f"message signature does not match {token.user}'s session"
                ) from None
            with self._lock:
                window = self._replay.get(token.session_id)
                if window is None:
                    window = self._replay[token.session_id] = ReplayWindow(token.expires_at)
                fresh = window.accept(envelope.seq)
            if not fresh:
                raise AuthError("unauthenticated", f"replayed message from {token.user} refused")
        except AuthError:
            self.rejected += 1
            raise
        return self.principal(token), decode(envelope.body, expected)

    def signer_of(self, key_expr: str, payload: object) -> str | None:
        """Who signed a message :meth:`open` refused, when that is certain: the user a
        token of this lab's registry names, whose session key signed these bytes for
        ``key_expr``, expired or revoked as the session may be. None for anything else:
        a token copied off the wire without its session key names nobody. For the
        audit trail's refusals, never for granting anything."""
        try:
            envelope = decode(payload, AuthEnvelope)
            self._registry_key.verify(envelope.token.token, envelope.token.signature)
            token = decode(envelope.token.token, SessionToken)
            nacl.signing.VerifyKey(token.session_key).verify(
                _signed_bytes(key_expr, envelope.seq, envelope.sent_at, envelope.body),
                envelope.signature,
            )
        except (MessageError, nacl.exceptions.BadSignatureError, ValueError, TypeError):
            return None
        return token.user if token.realm == self.realm else None

    def check_fresh(self, sent_at: float, who: str) -> None:
        """AuthError unless ``sent_at`` is within the freshness window of this service's clock."""
        now = self.clock()
        if abs(now - sent_at) > self.window:
            self.rejected += 1
            raise AuthError(
                "unauthenticated",
                f"message from {who} is {now - sent_at:+.1f} s off this service's clock "
                f"(allowed ±{self.window:.0f} s): check the clocks, or it is a replay",
            )

    def _prune_locked(self) -> None:
        now = self.clock()
        self._tokens = {k: t for k, t in self._tokens.items() if t.expires_at > now}
        self._replay = {k: w for k, w in self._replay.items() if w.expires_at > now}
        self._revoked = {k: e for k, e in self._revoked.items() if e > now}


def new_session_id() -> bytes:
    return secrets.token_bytes(16)


def issue_session(
    identity: RegistryIdentity,
    realm: str,
    user: str,
    permissions: Iterable[str],
    *,
    roles: Iterable[str] = (),
    grants: dict[str, list[str]] | None = None,
    ttl: float = 3600.0,
    keys: SessionKeys | None = None,
    now: float | None = None,
) -> Session:
    """A session signed by ``identity`` without a login round trip.

    The registry's login uses the same signing path; tests and tools that
    hold the registry key (``wart users``) use this directly.
    """
    keys = keys or SessionKeys()
    issued = time.time() if now is None else now
    token = SessionToken(
        realm=realm,
        user=user,
        session_id=new_session_id(),
        session_key=keys.session_public_key,
        box_key=keys.box_public_key,
        permissions=sorted(set(permissions)),  # type: ignore[arg-type]
        roles=sorted(set(roles)),
        issued_at=issued,
        expires_at=issued + ttl,
        grants={scope: sorted(set(p)) for scope, p in (grants or {}).items()},  # type: ignore[arg-type]
    )
    return Session(keys, identity.sign_token(token), token)


def resume_user(token: bytes) -> str:
    """The account a resume token names, unchecked (the registry checks it); ValueError."""
    try:
        return decode(decode(token, SignedResume).grant, ResumeGrant).user
    except MessageError as exc:
        raise ValueError(f"not a resume token: {exc}") from None
