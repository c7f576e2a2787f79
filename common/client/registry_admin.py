"""The registry's administration calls (the ``admin`` permission): a LabClient's part.

The client holds it (``client.admin``), given the realm, the registry's key and
the client's ask, and binds its calls as its own, so ``client.add_user(...)``
reads as it always did.
Passwords travel sealed to the registry's key, never in clear on the network.
"""

from __future__ import annotations

from typing import TypeVar

import nacl.public

from common import keys
from common.auth import registry_box_key
from common.client.client_ask import ClientAsk
from common.messages import (
    AddUser,
    AuditEntry,
    AuditList,
    AuditQuery,
    BanUser,
    ClearThrottle,
    Grant,
    KickFromServer,
    LiftBan,
    ListThrottles,
    ListUsers,
    Message,
    OkReply,
    RemoveUser,
    RenameServer,
    SetPassword,
    ThrottleInfo,
    ThrottleList,
    Ungrant,
    UnlockLogins,
    UserInfo,
    UserList,
)

M = TypeVar("M", bound=Message)


class RegistryAdminCalls:
    """Account and server administration; each call raises a LabError in the user's words."""

    def __init__(self, realm: str, registry_key: bytes, ask: ClientAsk) -> None:
        self.realm = realm
        self.registry_key = registry_key
        self._ask = ask

    def _admin(self, message: Message, what: str, expected: type[M] = OkReply) -> M:  # type: ignore[assignment]
        return self._ask(keys.registry_admin(self.realm), message, expected, what)

    def _seal_secret(self, secret: str) -> bytes:
        return bytes(
            nacl.public.SealedBox(registry_box_key(self.registry_key)).encrypt(secret.encode())
        )

    def list_users(self) -> list[UserInfo]:
        return self._admin(ListUsers(), "list users", UserList).users

    def add_user(
        self,
        user: str,
        password: str | None = None,
        roles: tuple[str, ...] = ("student",),
        public_key: bytes | None = None,
    ) -> str:
        sealed = self._seal_secret(password) if password is not None else None
        return self._admin(
            AddUser(user=user, roles=list(roles), sealed_password=sealed, public_key=public_key),
            f"add user {user}",
        ).detail

    def set_password(self, user: str, password: str, current: str | None = None) -> str:
        """``current``: one's own password now (needed unless an admin, or just logged in)."""
        sealed_current = self._seal_secret(current) if current else None
        return self._admin(
            SetPassword(
                user=user,
                sealed_password=self._seal_secret(password),
                sealed_current=sealed_current,
            ),
            f"set the password of {user}",
        ).detail

    def remove_user(self, user: str) -> str:
        return self._admin(RemoveUser(user=user), f"remove user {user}").detail

    def grant(self, user: str, grant: str, scope: str = "") -> str:
        return self._admin(
            Grant(user=user, grant=grant, scope=scope), f"grant {grant} to {user}"
        ).detail

    def ungrant(self, user: str, grant: str, scope: str = "") -> str:
        return self._admin(
            Ungrant(user=user, grant=grant, scope=scope), f"revoke {grant} from {user}"
        ).detail

    def kick_from_server(self, user: str, reason: str = "") -> str:
        return self._admin(KickFromServer(user=user, reason=reason), f"kick {user}").detail

    def rename_server(self, name: str) -> str:
        return self._admin(RenameServer(name=name), "rename the server").detail

    def throttles(self) -> list[ThrottleInfo]:
        """Every login throttle with a failure: (kind, key, failures, the wait now)."""
        return self._admin(ListThrottles(), "list login throttles", ThrottleList).throttles

    def clear_throttle(self, source: str) -> str:
        """Forget the failed logins of one source or network (a key ``throttles`` names)."""
        return self._admin(ClearThrottle(source=source), f"clear the throttle of {source}").detail

    def unlock_logins(self, user: str) -> str:
        """Forget the account's failed logins (admin): every source may try again at once."""
        return self._admin(UnlockLogins(user=user), f"unlock the logins of {user}").detail

    def ban(self, user: str, reason: str, until: float | None = None) -> str:
        """Keep ``user`` out until ``until`` (wall-clock s; None: until lifted), told why."""
        return self._admin(BanUser(user=user, reason=reason, until=until), f"ban {user}").detail

    def lift_ban(self, user: str, reason: str = "") -> str:
        return self._admin(LiftBan(user=user, reason=reason), f"lift the ban on {user}").detail

    def audit_trail(self, query: AuditQuery | None = None) -> tuple[list[AuditEntry], bool]:
        """The audit trail, newest first, filtered (admin); (entries, older ones match too)."""
        reply = self._ask(
            keys.registry_audit(self.realm),
            query or AuditQuery(),
            AuditList,
            "read the audit trail",
        )
        return reply.entries, reply.more
