"""Session tokens and the authenticated envelope (see common/auth.py)."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Bytes32, Bytes64, Ident, Message, NonNegInt

Permission = Literal[
    # people
    "join",  # enter a context (chat room, agent context)
    "chat",  # say something in a context
    "control",  # queue a controller on a robot
    "deploy",  # upload a controller for the runner to run
    "edit_map",  # edit a world live, save and load maps
    "kick",  # remove a user from a context
    "host",  # start new contexts and arenas
    "admin",  # accounts, grants, kick from the server
    # services
    "lease",  # issue leases on agents (agent contexts)
    "world",  # serve a world: frames, sensors, obey leases (engines, bridges)
    "run",  # run deployed controllers (runners)
    "vouch",  # say where a login through it comes from (the web viewer, a gateway)
]

ALL_PERMISSIONS: tuple[str, ...] = Permission.__args__  # type: ignore[attr-defined]

SessionId = Annotated[bytes, msgspec.Meta(min_length=16, max_length=16)]


class SessionToken(Message, frozen=True):
    """Who a session is and what it may do; signed by the registry."""

    realm: Ident
    user: Ident
    session_id: SessionId
    session_key: Bytes32  # Ed25519 verify key: signs every message of the session
    box_key: Bytes32  # X25519 public key: private messages are sealed to it
    permissions: list[Permission]  # global grants, roles expanded
    roles: list[Ident]
    issued_at: float
    expires_at: float
    # Grants in one scope ("ctx/<ctx>", "agent/<ctx>/<agent>") -> permissions there,
    # roles expanded (common.acl). Optional, so tokens without it still decode.
    grants: dict[str, list[Permission]] = msgspec.field(default_factory=dict)


class SignedToken(Message, frozen=True):
    token: bytes  # an encoded SessionToken
    signature: Bytes64  # the registry's Ed25519 signature of ``token``


class AuthEnvelope(Message, frozen=True):
    """A message from an authenticated session.

    ``signature`` is the session key's signature over the key expression it
    was sent on, ``seq``, ``sent_at`` and ``body`` (see ``common.auth``), so a
    message cannot be replayed, moved to another key or altered.
    """

    token: SignedToken
    seq: NonNegInt
    sent_at: float
    body: bytes  # an encoded message
    signature: Bytes64
