"""The admin folder of a lab's tab (admin permission; thesis 9.2.1: ACLs from the interface).

Accounts, passwords, grants (everywhere or in one context), kick from the
server, the server's name. Every action goes to the registry with the
admin's own session; the registry re-checks the admin permission, so this
folder is only shown to admins as a convenience, not as the protection.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import viser

from common.keys import is_ident
from viewers.web.adapters import Account, LabConnection, LabError
from viewers.web.inputs import set_value
from viewers.web.login import MAX_PASSWORD
from viewers.web.masked import add_masked_text
from viewers.web.text import escape_md

log = logging.getLogger("wart.viewer.admin")

ROLES = ("student", "instructor", "admin")
GRANTS = (
    "join",
    "chat",
    "control",
    "deploy",
    "edit_map",
    "kick",
    "host",
    "admin",
    "role:student",
    "role:instructor",
    "role:admin",
)
MAX_SERVER_NAME = 80


def format_accounts(accounts: list[Account]) -> str:
    if not accounts:
        return "_No accounts._"
    lines = [
        "| user | roles | grants | online | failed logins |",
        "| --- | --- | --- | --- | --- |",
    ]
    for a in accounts:
        grants = "; ".join(
            f"{escape_md(scope or 'everywhere')}: {', '.join(escape_md(g) for g in gs)}"
            for scope, gs in a.grants
            if gs
        )
        online = "yes" if a.online else ""
        lines.append(
            f"| {escape_md(a.name)} | {', '.join(escape_md(r) for r in a.roles)} | "
            f"{grants or '-'} | {online} | {a.failed_logins or ''} |"
        )
    return "\n".join(lines)


def check_scope(text: str) -> str | None:
    """A grant's scope as typed: empty (everywhere) or a context name. None if invalid."""
    text = text.strip()
    if not text:
        return ""
    if text.startswith("ctx/"):
        text = text[4:]
    return f"ctx/{text}" if is_ident(text) else None


class AdminPanel:
    def __init__(self, client: viser.ClientHandle, connection: LabConnection) -> None:
        self.client = client
        self.connection = connection
        gui = client.gui
        with gui.add_folder("Administration", expand_by_default=False):
            self.accounts_md = gui.add_markdown("_Press 'List accounts'._")
            self.list_button = gui.add_button("List accounts")
            self.user = gui.add_text("Account", "")
            # Shown as dots, and emptied as soon as it is used.
            self.password = add_masked_text(gui, "New password")
            self.role = gui.add_dropdown("Role", ROLES, initial_value="student")
            self.add_button = gui.add_button("Add account", color="green")
            self.password_button = gui.add_button("Set password")
            self.remove_button = gui.add_button("Remove account", color="red")
            self.unlock_button = gui.add_button("Unlock logins")
            self.grant = gui.add_dropdown("Permission or role", GRANTS, initial_value="edit_map")
            self.scope = gui.add_text("In context (empty: everywhere)", "")
            self.grant_button = gui.add_button("Grant")
            self.ungrant_button = gui.add_button("Revoke")
            self.reason = gui.add_text("Reason", "")
            self.kick_button = gui.add_button("Kick from server", color="red")
            self.server_name = gui.add_text("Server name", "")
            self.rename_button = gui.add_button("Rename server")
            self.notice = gui.add_markdown("", visible=False)
        self.list_button.on_click(lambda _: self.refresh())
        self.add_button.on_click(lambda _: self._add())
        self.password_button.on_click(lambda _: self._set_password())
        self.remove_button.on_click(lambda _: self._account_call(self.connection.remove_account))
        self.unlock_button.on_click(lambda _: self._account_call(self.connection.unlock_logins))
        self.grant_button.on_click(lambda _: self._grant(self.connection.grant))
        self.ungrant_button.on_click(lambda _: self._grant(self.connection.ungrant))
        self.kick_button.on_click(lambda _: self._kick())
        self.rename_button.on_click(lambda _: self._rename())

    def say(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def refresh(self) -> None:
        try:
            accounts = self.connection.list_accounts()
        except LabError as exc:
            self.say(f"Could not list accounts: {exc}")
            return
        self.accounts_md.content = format_accounts(accounts)

    def _target(self) -> str | None:
        user = self.user.value.strip()
        if not is_ident(user):
            self.say("Type the account's name: letters, digits, '_', '-' or '.'.")
            return None
        return user

    def _take_password(self) -> str | None:
        password = self.password.value
        set_value(self.password, "")  # never left on screen
        if not password:
            self.say("Type the new password.")
            return None
        if len(password) > MAX_PASSWORD:
            self.say("That password is too long.")
            return None
        return password

    def _done(self, call: Callable[[], str]) -> None:
        try:
            said = call()
        except LabError as exc:
            self.say(f"Refused: {exc}")
            return
        self.say(said or "Done.")
        self.refresh()

    def _add(self) -> None:
        user = self._target()
        password = self._take_password() if user else None
        if user and password:
            role = self.role.value
            self._done(lambda: self.connection.add_account(user, password, (role,)))

    def _set_password(self) -> None:
        user = self._target()
        password = self._take_password() if user else None
        if user and password:
            self._done(lambda: self.connection.set_password(user, password))

    def _account_call(self, call: Callable[[str], str]) -> None:
        user = self._target()
        if user:
            self._done(lambda: call(user))

    def _grant(self, call: Callable[[str, str, str], str]) -> None:
        user = self._target()
        scope = check_scope(self.scope.value)
        if user is None:
            return
        if scope is None:
            self.say("The context must be a name (letters, digits, '_', '-', '.'), or empty.")
            return
        grant = self.grant.value
        self._done(lambda: call(user, grant, scope))

    def _kick(self) -> None:
        user = self._target()
        reason = self.reason.value.strip()[:200]
        if user:
            self._done(lambda: self.connection.kick_from_server(user, reason))

    def _rename(self) -> None:
        name = self.server_name.value.strip()
        if not name or len(name) > MAX_SERVER_NAME or not name.isprintable():
            self.say(f"A server name is 1 to {MAX_SERVER_NAME} printable characters.")
            return
        self._done(lambda: self.connection.rename_server(name))
