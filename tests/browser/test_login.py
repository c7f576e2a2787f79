"""Log in through the page, and a wrong password says so in plain words."""

from __future__ import annotations

import pytest

from tests.browser.conftest import wait_until
from viewers.web.app import WebViewer

pytestmark = pytest.mark.browser


def test_login_and_wrong_password(open_page, viewer: WebViewer) -> None:
    page = open_page()
    page.log_in("wart://127.0.0.1:7447/lab", "ben", "not-the-password")
    page.wait_text("wrong user name or password")
    page.screenshot("wrong-password")

    page.fill("Password", "ben-pw")
    page.click("Log in")
    page.tab("lab@127.0.0.1").first.click()
    page.wait_text("Logged in as")
    page.wait_text("Online:")
    page.screenshot("lobby")
    session = next(iter(viewer.sessions.values()))
    assert [t.connection.user for t in session.labs.values()] == ["ben"]

    page.click("Log out")
    wait_until(lambda: not session.labs, what="the lab tab to close")
