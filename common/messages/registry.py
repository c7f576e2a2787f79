"""Wire types of the registry: login, directory, presence, admin, revocations, private messages.

Secrets never travel in the clear: a login request and any password in an
admin request are sealed (nacl SealedBox) to the registry's box key, and a
private message is a nacl Box from the sender's session box key to the
recipient's key. See docs/SECURITY.md.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.auth import SessionId, SignedToken
from common.messages.base import (
    Bytes32,
    Bytes64,
    Ident,
    Message,
    ShortText,
)

Password = Annotated[str, msgspec.Meta(min_length=1, max_length=1024)]
Scope = Annotated[str, msgspec.Meta(max_length=200)]
"""Where a grant applies: "" (everywhere), "ctx/<ctx>", "agent/<ctx>/<agent>" (common.acl)."""
GrantName = Annotated[str, msgspec.Meta(min_length=1, max_length=70)]
"""A permission ("kick") or a role ("role:instructor")."""


# --- login ------------------------------------------------------------------------


class PasswordCredential(Message, frozen=True):
    user: Ident
    password: Password


class KeyCredential(Message, frozen=True):
    """Proof of an Ed25519 identity key: a signature over the login's binding (common.acl)."""

    user: Ident
    public_key: Bytes32
    signed_at: float
    signature: Bytes64


class ResumeGrant(Message, frozen=True):
    """What a resume token says, signed by the registry: ``user`` may log in again
    without a password until ``expires_at``, unless the registry revoked ``resume_id``
    (logout, kick, ban, password change) or it was used (each is good once)."""

    realm: Ident
    user: Ident
    resume_id: SessionId
    issued_at: float
    expires_at: float


class SignedResume(Message, frozen=True):
    """A resume token as the client keeps it (a browser: in a cookie)."""

    grant: Annotated[bytes, msgspec.Meta(max_length=512)]  # an encoded ResumeGrant
    signature: Bytes64  # the registry's Ed25519 signature of ``grant``


class ResumeCredential(Message, frozen=True):
    """A login by a resume token instead of a password (no argon2id check)."""

    user: Ident
    token: Annotated[bytes, msgspec.Meta(max_length=1024)]  # an encoded SignedResume


class LoginRequest(Message, frozen=True):
    """What a client seals to the registry's box key to log in."""

    realm: Ident
    credential: PasswordCredential | KeyCredential | ResumeCredential
    session_key: Bytes32  # the new session's Ed25519 verify key
    box_key: Bytes32  # the new session's X25519 public key
    # The user's long-term X25519 key: offline messages are sealed to it. None (a
    # resume, which knows no password to derive it from): the mailbox is left as is.
    mailbox_key: Bytes32 | None
    ttl: Annotated[float, msgspec.Meta(gt=0)] = 12 * 3600.0
    # Where the attempt says it comes from: written by the client, so the registry
    # only logs it; it never makes a throttle source of its own (the source is the
    # querier's Zenoh session, or an address a gateway vouches for below).
    via: ShortText = ""
    # A gateway's word for where its person is: an encoded AuthEnvelope of a
    # LoginVouch sealed on registry/login by a session with ``vouch`` (the viewer).
    vouch: Annotated[bytes, msgspec.Meta(max_length=4096)] | None = None
    # Ask for a resume token in the reply (a browser that may reload its page).
    resume: bool = False


class LoginVouch(Message, frozen=True):
    """A gateway vouches that the login carrying it comes from ``address``.

    Bound to that login by its new session key, so it cannot be lifted onto another.
    """

    address: Annotated[str, msgspec.Meta(min_length=1, max_length=128)]
    session_key: Bytes32


class SealedLogin(Message, frozen=True):
    """The payload of a login query: a LoginRequest in a SealedBox to the registry."""

    sealed: Annotated[bytes, msgspec.Meta(max_length=8192)]


class PrivateMessage(Message, frozen=True):
    """A private message, encrypted end to end (nacl Box sender box key -> ``to_key``)."""

    sender: Ident
    recipient: Ident
    sender_box_key: Bytes32
    to_key: Bytes32  # which of the recipient's keys it is for (a session's, or the mailbox)
    ciphertext: Annotated[bytes, msgspec.Meta(max_length=8192)]  # nonce + box
    sent_at: float


class LoginReply(Message, frozen=True):
    token: SignedToken
    server_name: ShortText
    pending: list[PrivateMessage] = msgspec.field(default_factory=list)  # kept while offline
    resume: Annotated[bytes, msgspec.Meta(max_length=1024)] | None = None  # a SignedResume


class LogoutRequest(Message, frozen=True):
    # True when a page closes (a reload): its resume token stays good. A person's
    # "Log out" leaves it False: every session resumed from the same password
    # login ends too, with its resume token.
    keep_resume: bool = False
    # End every session and resume token of the account (a lost or stolen device).
    everywhere: bool = False


# --- directory ----------------------------------------------------------------------


class ContextInfoRequest(Message, frozen=True):
    """Asked (authenticated) on ctx/<ctx>/state by the registry for its directory."""


class ContextInfo(Message, frozen=True):
    """What a context says about itself in the directory."""

    ctx: Ident
    kind: Ident  # "chat", "agent"
    owner: Ident
    title: ShortText = ""
    members: list[Ident] = msgspec.field(default_factory=list)
    # An agent context's robots (its world's agents): whose twins its owner may keep.
    robots: Annotated[list[Ident], msgspec.Meta(max_length=1024)] = msgspec.field(
        default_factory=list
    )


class DirectoryRequest(Message, frozen=True):
    """Ask who and what is online."""


class DirectoryReply(Message, frozen=True):
    server_name: ShortText
    users: list[Ident]  # online: a live presence token and a session in force
    contexts: list[ContextInfo]


class UserKeysRequest(Message, frozen=True):
    """Where to send a private message to ``user``."""

    user: Ident


class UserKeysReply(Message, frozen=True):
    user: Ident
    online: bool
    session_box_keys: list[Bytes32]  # one per session in force (when online)
    mailbox_key: Bytes32 | None  # None: the user never logged in, nothing can be kept


class MailboxDeposit(Message, frozen=True):
    """Keep a private message for an offline user (still encrypted to their mailbox key)."""

    message: PrivateMessage


class MailboxClaim(Message, frozen=True):
    """A session's mailbox key, sent after its login (derived off the login's path):
    the registry records it and answers with the messages kept meanwhile."""

    mailbox_key: Bytes32


class ResumeCheck(Message, frozen=True):
    """Is my session's resume token still good? (not used up by asking; a refusal says why)

    A web viewer keeps a closed page's session for a reload (viewers/web/parking.py)
    and hands it back only to a page whose saved login the registry still honours.
    """

    token: Annotated[bytes, msgspec.Meta(max_length=1024)]  # an encoded SignedResume


class MailboxContents(Message, frozen=True):
    pending: list[PrivateMessage] = msgspec.field(default_factory=list)


# --- revocations ----------------------------------------------------------------------


class Revocation(Message, frozen=True):
    session_id: SessionId
    user: Ident
    expires_at: float  # the token's expiry: after it, the revocation can be forgotten
    reason: ShortText  # "logout", "kicked from the server: ...", "account removed"
    kicked: bool = False  # contexts announce a kick differently from a logout


class RevocationList(Message, frozen=True):
    revoked: list[Revocation]
    issued_at: float


class SignedRevocations(Message, frozen=True):
    """A RevocationList signed by the registry; published on registry/revocations and served."""

    body: bytes  # an encoded RevocationList
    signature: Bytes64


class RevocationsRequest(Message, frozen=True):
    """Ask for every revocation still in force (a service starting up)."""


class KickNotice(Message, frozen=True):
    """Sent by the registry (sealed as its own session) to a kicked user's inbox."""

    user: Ident
    reason: ShortText
    by: Ident


# --- admin --------------------------------------------------------------------------------


class BanInfo(Message, frozen=True):
    """A ban in force: who, why, since when and until when (None: until lifted)."""

    reason: ShortText
    by: Ident
    at: float
    until: float | None = None


class UserInfo(Message, frozen=True):
    name: Ident
    roles: list[Ident]
    grants: dict[Scope, list[GrantName]]  # scope -> permissions and roles granted there
    credentials: list[Ident]  # credential kinds: "password", "ed25519"
    online: bool = False
    failed_logins: int = 0  # failed logins on the account since its last unlock or restart
    ban: BanInfo | None = None  # the ban in force, if any


class ListUsers(Message, frozen=True):
    """An admin asks for every account, its rights and bans."""


class UserList(Message, frozen=True):
    users: list[UserInfo]


class AddUser(Message, frozen=True):
    """Create an account. ``sealed_password`` is the password sealed to the registry box key."""

    user: Ident
    roles: list[Ident] = msgspec.field(default_factory=lambda: ["student"])
    sealed_password: bytes | None = None
    public_key: Bytes32 | None = None


class SetPassword(Message, frozen=True):
    """Admins set anyone's password; a user may set their own with the current one
    (``sealed_current``, sealed like the new one), or without it from a session that
    logged in with the password minutes ago (never from a resumed one)."""

    user: Ident
    sealed_password: Annotated[bytes, msgspec.Meta(max_length=4096)]
    sealed_current: Annotated[bytes, msgspec.Meta(max_length=4096)] | None = None


class RemoveUser(Message, frozen=True):
    user: Ident


class Grant(Message, frozen=True):
    user: Ident
    grant: GrantName
    scope: Scope = ""


class Ungrant(Message, frozen=True):
    user: Ident
    grant: GrantName
    scope: Scope = ""


class KickFromServer(Message, frozen=True):
    user: Ident
    reason: ShortText = ""


class UnlockLogins(Message, frozen=True):
    """Forget the account's failed logins: every source may try again at once."""

    user: Ident


class ListThrottles(Message, frozen=True):
    """An admin asks for every login throttle with a failure (services/registry/throttle.py)."""


class ThrottleInfo(Message, frozen=True):
    kind: Literal["pair", "source", "network", "account"]
    key: ShortText  # "alice|zenoh:ab12", "zenoh:ab12", "viewer-web:10.0.0.0/24", "alice"
    failures: int
    wait_s: float  # how long a throttled attempt is told to wait now (0: not throttled)


class ThrottleList(Message, frozen=True):
    throttles: list[ThrottleInfo]


class ClearThrottle(Message, frozen=True):
    """Forget the failures of one source or network (as ``ThrottleInfo.key`` names it)."""

    source: Annotated[str, msgspec.Meta(min_length=1, max_length=256)]


class RenameServer(Message, frozen=True):
    name: Annotated[str, msgspec.Meta(min_length=1, max_length=80)]


class BanUser(Message, frozen=True):
    """Keep an account out: its sessions are revoked now and its logins refused until ``until``
    (wall-clock seconds; None: until lifted), with ``reason`` shown to it."""

    user: Ident
    reason: Annotated[str, msgspec.Meta(min_length=1, max_length=200)]
    until: float | None = None


class LiftBan(Message, frozen=True):
    user: Ident
    reason: Annotated[str, msgspec.Meta(max_length=200)] = ""


ADMIN_REQUESTS = (
    ListUsers,
    AddUser,
    SetPassword,
    RemoveUser,
    Grant,
    Ungrant,
    KickFromServer,
    RenameServer,
    UnlockLogins,
    BanUser,
    LiftBan,
    ListThrottles,
    ClearThrottle,
)

__all__ = [
    "ADMIN_REQUESTS",
    "AddUser",
    "BanInfo",
    "BanUser",
    "ClearThrottle",
    "ContextInfo",
    "ContextInfoRequest",
    "DirectoryReply",
    "DirectoryRequest",
    "Grant",
    "KeyCredential",
    "KickFromServer",
    "KickNotice",
    "LiftBan",
    "ListThrottles",
    "ListUsers",
    "LoginReply",
    "LoginRequest",
    "LoginVouch",
    "LogoutRequest",
    "MailboxClaim",
    "MailboxContents",
    "MailboxDeposit",
    "PasswordCredential",
    "PrivateMessage",
    "RemoveUser",
    "RenameServer",
    "ResumeCheck",
    "ResumeCredential",
    "ResumeGrant",
    "Revocation",
    "RevocationList",
    "RevocationsRequest",
    "SealedLogin",
    "SetPassword",
    "SignedResume",
    "SignedRevocations",
    "ThrottleInfo",
    "ThrottleList",
    "Ungrant",
    "UnlockLogins",
    "UserInfo",
    "UserKeysReply",
    "UserKeysRequest",
    "UserList",
]
