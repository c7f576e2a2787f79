"""A saved login in Chromium against a real lab (issue 38): reloading the page logs the
browser in again without the password; the cookie is HttpOnly and SameSite=Strict;
"Log out" ends it; a revoked one is refused in words and the password form comes back;
one that could not be tried now (a busy viewer, a frozen registry) is kept."""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from common.client.resume_cookie import PREFIX
from tests.browser.conftest import ViserPage, page_url
from tests.browser.test_real_lab import log_in, online
from tests.kit.reallab import RealLab, real_lab
from viewers.web.login import LoginDesk
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
    # The session parked when the page closed was not ended for a question not answered:
    # the page takes it back, as any reload within the grace does.
    page.wait_text("your session was kept while the page was away", timeout=30_000)
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


def _back_and_kept(context: Any, lab: RealLab, label: str, words: str) -> ViserPage:
    """The same browser loads the page again and its saved login cannot be tried now:
    ``words`` say why, the password form is offered, and the cookie is kept."""
    page = ViserPage(context.new_page(), label)
    page.p.goto(page_url(lab.viewer.url))
    page.wait_ready()
    page.wait_text(words, timeout=30_000)
    page.wait_text("It is kept: reload the page in a minute", timeout=10_000)
    page.p.wait_for_timeout(1000)  # a deletion would have come with the form
    assert _saved(page), "the saved login was deleted though nothing refused it"
    return page


def _logged_in_then_closed(open_page, lab: RealLab, user: str) -> Any:
    """``user``'s browser, its page logged in (a saved login) and closed; its context."""
    page = open_page(user)
    log_in(page, lab, user)
    _wait_saved(page, True)
    context = page.p.context
    page.p.close()
    return context


def test_a_saved_login_that_could_not_be_tried_now_is_kept_for_the_next_load(
    open_page, lab: RealLab
) -> None:
    """A busy viewer (a class reconnecting after a restart) or a registry that does not
    answer refuses nothing: the page says so and offers the password, and the cookie
    stays, so the next load logs in by it without the password."""
    context = _logged_in_then_closed(open_page, lab, "carol")
    # Every login thread of the viewer held, and a wait of half a second for one.
    busy = LoginDesk(workers=1, queue_wait=0.5)
    held = threading.Event()
    busy.submit(held.wait, lambda: None)
    usual, lab.viewer.logins = lab.viewer.logins, busy
    try:
        words = "this viewer is busy, many people are logging in at once"
        page = _back_and_kept(context, lab, "carol-busy", words)
    finally:
        lab.viewer.logins = usual
        held.set()
        busy.close()
    page.p.reload()
    page.wait_ready()
    page.tab(tab_label(lab.address)).first.click(timeout=30_000)
    page.wait_text("Logged in as", timeout=30_000)
    assert page.button("Log in").count() == 0


def test_a_saved_login_tried_while_the_registry_is_frozen_is_kept(open_page, lab: RealLab) -> None:
    """The registry restarting or hung (SIGSTOP here: no answer, no error) refuses
    nothing either: the words say it does not answer, the cookie stays, and the session
    the closed page left parked is not ended for it."""
    context = _logged_in_then_closed(open_page, lab, "alice")
    registry = lab.lab.registry
    assert registry is not None
    wait, lab.connector.login_wait = lab.connector.login_wait, 2.0
    os.kill(registry.popen.pid, signal.SIGSTOP)
    try:
        page = _back_and_kept(context, lab, "alice-frozen", "does not answer")
    finally:
        os.kill(registry.popen.pid, signal.SIGCONT)
        lab.connector.login_wait = wait
    page.p.reload()
    page.wait_ready()
    # The session parked when the page closed was not ended for a question not answered:
    # the page takes it back, as any reload within the grace does.
    page.wait_text("your session was kept while the page was away", timeout=30_000)
    page.tab(tab_label(lab.address)).first.click(timeout=30_000)
    page.wait_text("Logged in as", timeout=30_000)
