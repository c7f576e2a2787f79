"""The demo lab's account administration: a user's admin calls on the in-memory lab.

A part a DemoConnection holds (``connection.admin``): accounts, grants, kicks
from the server, bans (none), the audit trail (none), the server's name.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from common.messages.audit import AuditEntry, AuditQuery
from viewers.web.adapters import Account, DirectoryEvent, DisconnectedEvent, LabError

if TYPE_CHECKING:
    from viewers.web.demo_lab import DemoLab

STUDENT = frozenset({"join", "chat", "control", "deploy"})
INSTRUCTOR = STUDENT | {"edit_map", "kick", "host"}
ADMIN = INSTRUCTOR | {"admin"}


class DemoAdmin:
    """The admin calls of a DemoConnection: its user's, checked by its permission guard."""

    def __init__(self, lab: DemoLab, user: str, need: Callable[[str, str], None]) -> None:
        self._lab = lab
        self._user = user
        self._need = need

    def list_accounts(self) -> list[Account]:
        self._need("admin", "manage accounts")
        with self._lab._lock:
            return [
                Account(name, (), (("", tuple(sorted(perms))),), name in self._lab._online)
                for name, (_pw, perms) in sorted(self._lab.accounts.items())
            ]

    def add_account(self, user: str, password: str, roles: tuple[str, ...]) -> str:
        self._need("admin", "manage accounts")
        with self._lab._lock:
            if user in self._lab.accounts:
                raise LabError(f"{user} already exists")
            perms = INSTRUCTOR if "instructor" in roles else STUDENT
            self._lab.accounts[user] = (password, perms)
        return f"added {user}"

    def set_password(self, user: str, password: str, current: str | None = None) -> str:
        if user != self._user:  # one's own password needs no permission, as in a lab
            self._need("admin", "manage accounts")
        elif current is not None and current != self._lab.accounts.get(user, ("",))[0]:
            raise LabError("your current password is wrong")
        if len(password) < 8:
            raise LabError("a password needs at least 8 characters")
        with self._lab._lock:
            if user not in self._lab.accounts:
                raise LabError(f"there is no user {user}")
            self._lab.accounts[user] = (password, self._lab.accounts[user][1])
        return f"password of {user} set"

    def remove_account(self, user: str) -> str:
        self._need("admin", "manage accounts")
        with self._lab._lock:
            if self._lab.accounts.pop(user, None) is None:
                raise LabError(f"there is no user {user}")
        return f"removed {user}"

    def grant(self, user: str, grant: str, scope: str = "") -> str:
        self._change_perms(user, lambda perms: perms | {grant})
        return f"granted {grant} to {user}"

    def ungrant(self, user: str, grant: str, scope: str = "") -> str:
        self._change_perms(user, lambda perms: perms - {grant})
        return f"revoked {grant} from {user}"

    def _change_perms(self, user: str, change: Callable[[frozenset[str]], frozenset[str]]) -> None:
        """``user``'s permissions replaced by ``change`` of them (an admin's call)."""
        self._need("admin", "manage accounts")
        with self._lab._lock:
            if user not in self._lab.accounts:
                raise LabError(f"there is no user {user}")
            pw, perms = self._lab.accounts[user]
            self._lab.accounts[user] = (pw, change(perms))

    def kick_from_server(self, user: str, reason: str = "") -> str:
        self._need("admin", "kick people from the server")
        self._lab._broadcast(
            DisconnectedEvent(f"kicked from the server by {self._user}: {reason}"), only={user}
        )
        return f"kicked {user}"

    def unlock_logins(self, user: str) -> str:
        self._need("admin", "unlock logins")
        return f"failed logins of {user} forgotten: they may log in now"

    def ban(self, user: str, reason: str, until: float | None) -> str:
        raise LabError("the demo lab has no bans: a real lab's registry keeps them")

    def lift_ban(self, user: str) -> str:
        raise LabError("the demo lab has no bans")

    def audit_trail(self, query: AuditQuery) -> list[AuditEntry]:
        self._need("admin", "read the audit trail")
        return []  # the demo lab keeps no audit trail

    def rename_server(self, name: str) -> str:
        self._need("admin", "rename the server")
        self._lab.server_name = name
        self._lab._broadcast(DirectoryEvent())
        return f"renamed to {name}"
