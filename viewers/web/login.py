"""The login form: a modal in one browser only (viser GUI is per client).

viser has no login hook and no masked text input: the password field shows
dots through a style rule (viewers/web/masked.py), is cleared as soon as the
attempt is made, and a deployment that leaves the lab network should sit
behind an HTTPS reverse proxy (docs/OPERATIONS.md).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import viser

from common.keys import is_ident
from viewers.web.adapters import LabConnection, LabConnector, LabError
from viewers.web.address import LabAddress
from viewers.web.masked import add_masked_text

log = logging.getLogger("wart.viewer.login")

MAX_PASSWORD = 1024


def check_login_input(user: str, password: str) -> str | None:
    """What is wrong with the typed user/password, in plain words (None: nothing)."""
    if not user:
        return "Type your user name."
    if not is_ident(user):
        return "A user name has only letters, digits, '_', '-' or '.'."
    if not password:
        return "Type your password."
    if len(password) > MAX_PASSWORD:
        return "That password is too long."
    return None


class LoginForm:
    """Asks for a user and password, calls the connector, reports plain-words errors."""

    def __init__(
        self,
        client: viser.ClientHandle,
        connector: LabConnector,
        address: LabAddress,
        on_success: Callable[[LabConnection], None],
    ) -> None:
        self.client = client
        self.connector = connector
        self.address = address
        self.on_success = on_success
        self.closed = False
        # Held back until the handlers below are registered: viser sends each button
        # as it is made, and a click that reaches the viewer before its handler is
        # dropped without a trace. On a loaded viewer the thread building the form can
        # wait for the GIL long enough for a quick browser to click "Log in" in between
        # (seen: 1 to 2 of 100 headless logins at load 11 to 17); that student's form
        # then stayed on screen with no answer, for good.
        with client.atomic():
            self.modal = client.gui.add_modal(f"Log in to {address.label}")
            with self.modal:
                client.gui.add_markdown(f"Lab at `{address.url(with_user=False)}`")
                self.user = client.gui.add_text("User", address.user or "")
                self.password = add_masked_text(client.gui, "Password")
                self.error = client.gui.add_markdown("", visible=False)
                self.submit = client.gui.add_button("Log in", color="green")
                self.cancel = client.gui.add_button("Cancel")
            self.submit.on_click(lambda _: self.attempt())
            self.cancel.on_click(lambda _: self.close())

    def show_error(self, text: str) -> None:
        self.error.content = f"**{text}**"
        self.error.visible = True

    def attempt(self) -> bool:
        user = self.user.value.strip()
        password = self.password.value
        self.password.value = ""  # never leave it on screen or in the GUI state
        problem = check_login_input(user, password)
        if problem:
            self.show_error(problem)
            return False
        self.submit.disabled = True
        try:
            connection = self.connector.login(
                self.address.with_user(user), user, password, via=f"browser-{self.client.client_id}"
            )
        except LabError as exc:
            self.show_error(f"Could not log in: {exc}")
            return False
        except (OSError, TimeoutError) as exc:
            log.info("login to %s failed: %s", self.address.label, exc)
            self.show_error(f"Could not reach the lab at {self.address.label}.")
            return False
        finally:
            self.submit.disabled = False
        self.close()
        self.on_success(connection)
        return True

    def close(self) -> None:
        self.closed = True
        self.modal.close()
