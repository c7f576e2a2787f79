"""A saved login in Chromium against a real lab (issue 38): reloading the page logs the
browser in again without the password; the cookie is HttpOnly and SameSite=Strict;
"Log out" ends it; a revoked one is refused in words and the password form comes back."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from common.client.resume_cookie import PREFIX
from tests.browser.conftest import ViserPage, page_url
from tests.browser.test_real_lab import log_in, online
from tests.kit.reallab import RealLab, real_lab
from viewers.web.tabs import tab_label

pytestmark = pytest.mark.real_lab


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("savedlab"))) as env:
        yield env


def _saved(page) -> list[str]:
    cookies = page.p.context.cookies()
    return [c["name"] for c in cookies if c["name"].startswith(PREFIX) and c["value"]]


def _wait_saved(page, want: bool) -> None:
    for _ in range(100):
        if bool(_saved(page)) == want:
            return
        page.p.wait_for_timeout(100)
    raise AssertionError(f"the page's saved login: wanted {want}, cookies {_saved(page)}")


def test_a_reload_resumes_without_the_password_and_log_out_forgets(open_page, lab: RealLab) -> None:
    page = open_page("alice")
    log_in(page, lab, "alice")
    _wait_saved(page, True)
    # No script in the page can read it (an injected one included), nor another site send it.
    (saved,) = [c for c in page.p.context.cookies() if c["name"].startswith(PREFIX)]
    assert saved["httpOnly"] and saved["sameSite"] == "Strict" and not saved["secure"]
    assert PREFIX not in page.p.evaluate("document.cookie")
    page.p.reload()
    page.wait_ready()
    # No password typed: the lab's tab comes back by itself, as alice.
    page.tab(tab_label(lab.address)).first.click(timeout=30_000)
    page.wait_text("Logged in as", timeout=30_000)
    assert page.button("Log in").count() == 0
    assert "alice" in online(lab)
    page.screenshot("resumed")
    # A second reload resumes again (each resume gives the page a new token).
    page.p.reload()
    page.wait_ready()
    page.tab(tab_label(lab.address)).first.click(timeout=30_000)
    page.wait_text("Logged in as", timeout=30_000)
    # "Log out" revokes it and deletes the cookie: the next load asks for the password.
    page.click("Log out")
    _wait_saved(page, False)
    page.p.reload()
    page.wait_ready()
    page.p.wait_for_timeout(1500)
    assert page.tab(tab_label(lab.address)).count() == 0


def test_a_saved_login_revoked_meanwhile_is_refused_in_words(open_page, lab: RealLab) -> None:
    page = open_page("bob")
    log_in(page, lab, "bob")
    _wait_saved(page, True)
    context = page.p.context
    page.p.close()  # bob closes the page; an admin changes his password meanwhile
    with lab.lab.client("admin") as admin:
        admin.set_password("bob", "a new password for bob")
    page = ViserPage(context.new_page(), "bob-again")  # the same browser, its cookies
    page.p.goto(page_url(lab.viewer.url))
    page.wait_ready()
    page.wait_text("Could not log in again with your saved login", timeout=30_000)
    page.wait_text("the password was changed", timeout=10_000)
    page.button("Log in").wait_for(timeout=10_000)  # the password form, for bob
    page.screenshot("saved-login-refused")
