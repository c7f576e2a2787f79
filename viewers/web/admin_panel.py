"""The admin folder of a lab's tab (admin permission; thesis 9.2.1: ACLs from the interface).

Accounts, passwords, grants (everywhere or in one context), kick from the
server, bans (with a reason and an end), the audit trail (filtered), the
server's name. Every action goes to the registry with the
admin's own session; the registry re-checks the admin permission, so this
folder is only shown to admins as a convenience, not as the protection.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Literal

import viser

from common.keys import is_ident
from common.messages.audit import AuditEntry, AuditQuery
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
MAX_BAN_HOURS = 24 * 365
AUDIT_PAGE = 100  # lines shown at once: the CLI (wart audit) exports the rest
OUTCOMES = ("any", "ok", "refused")


def format_accounts(accounts: list[Account]) -> str:
    if not accounts:
        return "_No accounts._"
    lines = [
        "| user | roles | grants | online | failed logins | banned |",
        "| --- | --- | --- | --- | --- | --- |",
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
            f"{grants or '-'} | {online} | {a.failed_logins or ''} | {escape_md(a.banned)} |"
        )
    return "\n".join(lines)


def format_audit(entries: list[AuditEntry]) -> str:
    """The audit trail as a table, newest first (times in UTC)."""
    if not entries:
        return "_No audit lines match._"
    lines = [
        "| when (UTC) | who | did | on | outcome | detail | from |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for e in entries:
        at = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(e.at))
        where = e.source if e.reporter == "registry" else f"{e.source} via {e.reporter}"
        lines.append(
            f"| {at} | {escape_md(e.actor)} | {escape_md(e.action)} | {escape_md(e.target)} | "
            f"{e.outcome} | {escape_md(e.detail)} | {escape_md(where)} |"
        )
    return "\n".join(lines)


def check_hours(text: str) -> float | str | None:
    """A ban's length as typed, in hours: None (until lifted), the end, or an error's words."""
    text = text.strip()
    if not text:
        return None
    try:
        hours = float(text)
    except ValueError:
        return "Ban for: a number of hours (0.5, 24, 168), or empty for until lifted."
    if not 0 < hours <= MAX_BAN_HOURS:
        return f"Ban for: more than 0 and at most {MAX_BAN_HOURS} hours."
    return time.time() + hours * 3600.0


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
        admin = connection.admin
        # Each button's answer shows right under it, where the eye already is (one notice at
        # the foot of the form was off-screen on a laptop); another button's answer hides it.
        self._notices: list[viser.GuiMarkdownHandle] = []
        with gui.add_folder("Administration", expand_by_default=False):
            self.user = gui.add_text("Account", "")
            # Shown as dots, and emptied as soon as it is used.
            self.password = add_masked_text(gui, "New password")
            self.role = gui.add_dropdown("Role", ROLES, initial_value="student")
            self.add_button = self._button(gui, "Add account", self._add, color="green")
            self.password_button = self._button(gui, "Set password", self._set_password)
            self.remove_button = self._button(
                gui,
                "Remove account",
                lambda: self._account_call(admin.remove_account),
                color="red",
            )
            self.unlock_button = self._button(
                gui, "Unlock logins", lambda: self._account_call(admin.unlock_logins)
            )
            # Below the buttons: a longer list after a change does not push them down.
            self.list_button = self._button(gui, "List accounts", self.refresh)
            self.accounts_md = gui.add_markdown("_Press 'List accounts'._")
            self.grant = gui.add_dropdown("Permission or role", GRANTS, initial_value="edit_map")
            self.scope = gui.add_text("In context (empty: everywhere)", "")
            self.grant_button = self._button(gui, "Grant", lambda: self._grant(admin.grant))
            self.ungrant_button = self._button(gui, "Revoke", lambda: self._grant(admin.ungrant))
            self.reason = gui.add_text("Reason", "")
            self.kick_button = self._button(gui, "Kick from server", self._kick, color="red")
            self.ban_hours = gui.add_text("Ban for (hours; empty: until lifted)", "")
            self.ban_button = self._button(gui, "Ban", self._ban, color="red")
            self.lift_button = self._button(
                gui, "Lift ban", lambda: self._account_call(admin.lift_ban)
            )
            self.server_name = gui.add_text("Server name", "")
            self.rename_button = self._button(gui, "Rename server", self._rename)
            with gui.add_folder("Audit trail", expand_by_default=False):
                self.audit_actor = gui.add_text("Who (account)", "")
                self.audit_action = gui.add_text("Action (kick, ban, grant, estop...)", "")
                self.audit_target = gui.add_text("On (contains)", "")
                self.audit_outcome = gui.add_dropdown("Outcome", OUTCOMES, initial_value="any")
                self.audit_button = self._button(gui, "Show audit trail", self.show_audit)
                self.audit_md = gui.add_markdown("_Press 'Show audit trail'._")
        self.notice = self._notices[0]  # where say() writes: under the button last pressed

    def _button(
        self,
        gui: viser.GuiApi,
        label: str,
        act: Callable[[], object],
        color: Literal["green", "red"] | None = None,
    ) -> viser.GuiButtonHandle:
        """A button and, right under it, where its answer shows."""
        button = gui.add_button(label, color=color)
        notice = gui.add_markdown("", visible=False)
        self._notices.append(notice)
        button.on_click(self._on_press(notice, act))
        return button

    def _on_press(
        self, notice: viser.GuiMarkdownHandle, act: Callable[[], object]
    ) -> Callable[[viser.GuiEvent], None]:
        """The pressed button's answer goes under it; the one shown before is cleared."""

        def pressed(_event: viser.GuiEvent) -> None:
            if self.notice is not notice:
                self.notice.visible = False
            self.notice = notice
            act()

        return pressed

    def say(self, text: str) -> None:
        self.notice.content = f"**{escape_md(text)}**"
        self.notice.visible = True

    def refresh(self) -> None:
        try:
            accounts = self.connection.admin.list_accounts()
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
            self._done(lambda: self.connection.admin.add_account(user, password, (role,)))

    def _set_password(self) -> None:
        user = self._target()
        password = self._take_password() if user else None
        if user and password:
            self._done(lambda: self.connection.admin.set_password(user, password))

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
            self._done(lambda: self.connection.admin.kick_from_server(user, reason))

    def _rename(self) -> None:
        name = self.server_name.value.strip()
        if not name or len(name) > MAX_SERVER_NAME or not name.isprintable():
            self.say(f"A server name is 1 to {MAX_SERVER_NAME} printable characters.")
            return
        self._done(lambda: self.connection.admin.rename_server(name))

    def _ban(self) -> None:
        user = self._target()
        if user is None:
            return
        reason = self.reason.value.strip()[:200]
        if not reason:
            self.say("Type the reason: the banned user is told it at each login.")
            return
        until = check_hours(self.ban_hours.value)
        if isinstance(until, str):
            self.say(until)
            return
        self._done(lambda: self.connection.admin.ban(user, reason, until))

    def show_audit(self) -> None:
        """The audit trail, filtered as typed (every filter checked before it is sent)."""
        actor = self.audit_actor.value.strip()
        action = self.audit_action.value.strip().lower()
        target = self.audit_target.value.strip()[:200]
        if actor and not is_ident(actor):
            self.say("Who: an account name (letters, digits, '_', '-' or '.'), or empty.")
            return
        if action and not (len(action) <= 40 and action.replace("_", "").isalnum()):
            self.say("Action: a short name such as kick, ban, grant, estop, or empty.")
            return
        outcome = self.audit_outcome.value
        query = AuditQuery(
            actor=actor,
            action=action,
            target=target,
            outcome="" if outcome == "any" else outcome,  # type: ignore[arg-type]
            limit=AUDIT_PAGE,
        )
        try:
            entries = self.connection.admin.audit_trail(query)
        except LabError as exc:
            self.say(f"Could not read the audit trail: {exc}")
            return
        self.audit_md.content = format_audit(entries)
