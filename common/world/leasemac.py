"""Per-lease session keys: agent commands MACed instead of signed (docs/SECURITY.md).

An Ed25519 verification costs the world 60-150 µs per command, serially in
its subscriber thread; 20 controllers answering one tick then queue behind
each other for milliseconds. Under a *MAC lease* the agent context picks a
random 32-byte key K when it grants the lease and seals K (a) to the
holder's session box key and (b) to the world's box key, named by the
world's registry-signed token (service accounts with the ``world``
permission). Both copies travel inside the lease, which stays an Ed25519
envelope signed by the context. The holder then sends a
:class:`~common.messages.MacCommand`: a keyed BLAKE2b over the key
expression, lease id, sequence number, send time and command body. The
world checks it in a few µs.

Only the context, the holder and the world know K; a non-holder who knows
the lease id cannot produce a valid MAC. The world still requires the lease
to be in force, a fresh ``sent_at`` and an unseen ``seq`` (per lease).
"""

from __future__ import annotations

import contextlib
import hashlib
import hmac
import secrets
import struct
import threading
from collections.abc import Callable
from typing import Any

import msgspec
import nacl.exceptions
import nacl.public

from common.auth import AuthError, Session, Verifier
from common.lab_errors import NotLoggedIn
from common.messages import (
    MacCommand,
    Message,
    SessionToken,
    SignedToken,
    WorldSnapshot,
    encode,
)

LEASE_KEY_BYTES = 32
MAC_BYTES = 32
_PERSON = b"wart.cmd.v1"  # BLAKE2b personalisation: a command MAC is never valid as another MAC
# A MacCommandBundle item's MAC: personalised apart, so an item's MAC is never a
# MacCommand's (or the reverse), whatever bytes either covers.
_ITEM_PERSON = b"wart.cmdarr.v1"
_SEQ_TIME = struct.Struct("<Qd")  # a command's sequence number and send time, as hashed


def new_lease_key() -> bytes:
    return secrets.token_bytes(LEASE_KEY_BYTES)


def seal_key(lease_key: bytes, box_public_key: bytes) -> bytes:
    """K sealed (anonymous sender) to one X25519 public key."""
    return nacl.public.SealedBox(nacl.public.PublicKey(box_public_key)).encrypt(lease_key)


def open_key(sealed: bytes, box_private_key: nacl.public.PrivateKey) -> bytes:
    """K from ``seal_key``'s output; AuthError if it was not sealed to this key."""
    try:
        key = nacl.public.SealedBox(box_private_key).decrypt(sealed)
    except nacl.exceptions.CryptoError:
        raise AuthError("unauthenticated", "lease key not sealed to this session") from None
    if len(key) != LEASE_KEY_BYTES:
        raise AuthError("unauthenticated", f"lease key has {len(key)} bytes, not 32")
    return key


class CommandMac:
    """The MACs of one lease's commands on one key expression.

    The fields fixed for the lease (its key, the key expression, the lease
    id) are hashed once; each command then only hashes its sequence number,
    time and body into a copy. Sender and world both do this at 50 Hz per
    robot, where a fresh keyed hash per command was a third of the MAC's cost.
    """

    __slots__ = ("_item_prefix", "_prefix", "lease_id")

    def __init__(self, lease_key: bytes, key_expr: str, lease_id: str) -> None:
        self.lease_id = lease_id
        self._prefix = _mac_prefix(lease_key, _PERSON, key_expr, lease_id)
        self._item_prefix = _mac_prefix(lease_key, _ITEM_PERSON, key_expr, lease_id)

    def item_tag(self, record: bytes) -> bytes:
        """The MAC of one MacCommandBundle item: its record's bytes exactly as they travel
        (``MAC_ITEM_STRUCT``: seq, sent_at, flags, speeds, counters), bound to this key
        expression and lease."""
        h = self._item_prefix.copy()
        h.update(record)
        return h.digest()

    def tag(self, seq: int, sent_at: float, body: bytes) -> bytes:
        """The MAC of one command: bound to its key expression, lease, order and time."""
        h = self._prefix.copy()
        h.update(_SEQ_TIME.pack(seq, sent_at))
        h.update(body)
        return h.digest()

    def command(self, seq: int, message: Message, now: float) -> bytes:
        """The encoded MacCommand carrying ``message`` on this key expression."""
        body = encode(message)
        # tag() inlined: this runs 50 times a second per robot on the sender.
        h = self._prefix.copy()
        h.update(_SEQ_TIME.pack(seq, now))
        h.update(body)
        return encode(
            MacCommand(lease_id=self.lease_id, seq=seq, sent_at=now, body=body, mac=h.digest())
        )


def _mac_prefix(lease_key: bytes, person: bytes, key_expr: str, lease_id: str) -> Any:
    """Keyed BLAKE2b (32 bytes) over the length-prefixed key expression and lease id."""
    key = key_expr.encode()
    lid = lease_id.encode()
    prefix = hashlib.blake2b(key=lease_key, digest_size=MAC_BYTES, person=person)
    # Length prefixes keep the fields apart: no two field splits hash alike.
    prefix.update(struct.pack("<II", len(key), len(lid)))
    prefix.update(key)
    prefix.update(lid)
    return prefix


def item_mac(lease_key: bytes, key_expr: str, lease_id: str, record: bytes) -> bytes:
    """The MAC of one MacCommandBundle item (:meth:`CommandMac.item_tag`, for a single use)."""
    return CommandMac(lease_key, key_expr, lease_id).item_tag(record)


def command_mac(
    lease_key: bytes, key_expr: str, lease_id: str, seq: int, sent_at: float, body: bytes
) -> bytes:
    """The MAC of one command (:class:`CommandMac`, for a single use)."""
    return CommandMac(lease_key, key_expr, lease_id).tag(seq, sent_at, body)


def mac_command(
    lease_key: bytes, key_expr: str, lease_id: str, seq: int, message: Message, now: float
) -> bytes:
    """The encoded MacCommand carrying ``message`` to ``key_expr`` under a MAC lease
    (:class:`CommandMac`, for a single use)."""
    return CommandMac(lease_key, key_expr, lease_id).command(seq, message, now)


def mac_matches(expected: bytes, received: bytes) -> bool:
    """Constant-time comparison: timing must not reveal how many MAC bytes were right."""
    return hmac.compare_digest(expected, received)


def check_world_token(verifier: Verifier, signed: SignedToken, world: str) -> SessionToken:
    """A world's identity token, if the registry signed it for this realm with ``world``.

    The context seals K only to such a token's box key: a forged or expired
    token, or an account without the ``world`` permission, gets AuthError.
    ``world`` names the world for the error message only: any service account
    with ``world`` may serve any world of the realm (as for leases).
    """
    token = verifier.verify_token(signed)
    if "world" not in token.permissions:
        raise AuthError(
            "forbidden",
            f"{token.user} advertises itself as world {world} without the 'world' permission",
        )
    return token


class WorldBoxKeys:
    """The box private keys a world's identity has used; finds the one a lease key is sealed to.

    A service login renews its session (new keys) before expiry; leases
    sealed to the previous box key must still open until the context reseals
    them, so the last few are kept. Thread-safe.
    """

    KEEP = 4

    def __init__(self, session: Callable[[], Session]) -> None:
        self._session = session
        self._keys: dict[bytes, nacl.public.PrivateKey] = {}
        self._lock = threading.Lock()

    def current(self) -> Session:
        """The current session (remembering its box key)."""
        session = self._session()
        with self._lock:
            if session.keys.box_public_key not in self._keys:
                self._keys[session.keys.box_public_key] = session.keys.box_key
                while len(self._keys) > self.KEEP:
                    self._keys.pop(next(iter(self._keys)))
        return session

    def private_for(self, box_public_key: bytes) -> nacl.public.PrivateKey | None:
        with contextlib.suppress(NotLoggedIn):  # not logged in (yet): remembered keys answer
            self.current()
        with self._lock:
            return self._keys.get(box_public_key)


def snapshot_with_identity(snap: Message, box_keys: WorldBoxKeys | None) -> Message:
    """A world's snapshot with its identity token, when it has one (MAC leases)."""
    if box_keys is None or not isinstance(snap, WorldSnapshot):
        return snap
    try:
        token = box_keys.current().signed_token
    except NotLoggedIn:
        return snap  # between logins: the context asks again in a few seconds
    return msgspec.structs.replace(snap, identity=token)
