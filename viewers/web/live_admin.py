"""A live connection's administration calls: accounts, grants, kicks, bans, the audit trail.

A part a LiveConnection holds (``connection.admin``): each call goes to the registry
through the user's LabClient, and its refusal comes back as a LabError.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from common.client import lab_client as lab
from common.messages import AuditEntry, AuditQuery, BanInfo
from viewers.web.adapters import Account


class LiveAdmin:
    """The admin calls of a LiveConnection, through its client and its call guard."""

    def __init__(self, client: lab.LabClient, call: Callable[[Callable[[], Any]], Any]) -> None:
        self.client = client
        self._call = call

    def list_accounts(self) -> list[Account]:
        users = self._call(self.client.list_users)
        return [
            Account(
                u.name,
                tuple(u.roles),
                tuple(sorted((scope, tuple(g)) for scope, g in u.grants.items())),
                u.online,
                u.failed_logins,
                ban_words(u.ban),
            )
            for u in users
        ]

    def add_account(self, user: str, password: str, roles: tuple[str, ...]) -> str:
        return str(self._call(lambda: self.client.add_user(user, password, roles)))

    def set_password(self, user: str, password: str, current: str | None = None) -> str:
        return str(self._call(lambda: self.client.set_password(user, password, current)))

    def remove_account(self, user: str) -> str:
        return str(self._call(lambda: self.client.remove_user(user)))

    def grant(self, user: str, grant: str, scope: str = "") -> str:
        return str(self._call(lambda: self.client.grant(user, grant, scope)))

    def ungrant(self, user: str, grant: str, scope: str = "") -> str:
        return str(self._call(lambda: self.client.ungrant(user, grant, scope)))

    def kick_from_server(self, user: str, reason: str = "") -> str:
        return str(self._call(lambda: self.client.kick_from_server(user, reason)))

    def rename_server(self, name: str) -> str:
        return str(self._call(lambda: self.client.rename_server(name)))

    def unlock_logins(self, user: str) -> str:
        return str(self._call(lambda: self.client.unlock_logins(user)))

    def ban(self, user: str, reason: str, until: float | None) -> str:
        return str(self._call(lambda: self.client.ban(user, reason, until)))

    def lift_ban(self, user: str) -> str:
        return str(self._call(lambda: self.client.lift_ban(user)))

    def audit_trail(self, query: AuditQuery) -> list[AuditEntry]:
        entries, _more = self._call(lambda: self.client.audit_trail(query))
        return list(entries)


def ban_words(ban: BanInfo | None) -> str:
    """A ban in force, for the admin's account list ("" if none)."""
    if ban is None:
        return ""
    end = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(ban.until)) if ban.until else "lifted"
    return f"until {end}: {ban.reason}"
