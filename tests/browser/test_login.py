"""Log in through the page; a wrong password says so in plain words; passwords show as dots."""

from __future__ import annotations

import io

import numpy as np
import pytest
from playwright.sync_api import expect

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
    # The page goes to the lab's tab by itself; its short name has the full one on hover.
    lab_tab = page.tab("lab@127.0.0.1").first
    expect(lab_tab).to_have_attribute("aria-selected", "true", timeout=15_000)
    assert lab_tab.inner_text().strip() == "lab@127.0.0.1"
    expect(lab_tab).to_have_attribute("title", "lab at 127.0.0.1:7447")
    page.wait_text("Logged in as")
    page.wait_text("Online:")
    page.screenshot("lobby")
    session = next(iter(viewer.sessions.values()))
    assert [t.connection.user for t in session.labs.values()] == ["ben"]

    # Join goes to the arena's tab and shows its world.
    page.click("Join arena")
    arena_tab = page.tab("arena (arena)").last
    expect(arena_tab).to_have_attribute("aria-selected", "true", timeout=15_000)
    expect(lab_tab).to_have_attribute("aria-selected", "false")
    wait_until(
        lambda: session.watching is not None and session.watching.ctx == "arena",
        what="the joined arena in the world view",
    )
    assert session.view.feed is not None
    lab_tab.click()

    page.click("Log out")
    wait_until(lambda: not session.labs, what="the lab tab to close")


SECRET = "hunter2-secret"


def text_security(page, label: str) -> str:
    return page.input_after_label(label).evaluate("e => getComputedStyle(e).webkitTextSecurity")


def field_ink(page, label: str) -> np.ndarray:
    """How dark each pixel inside a field's border is (0: background)."""
    from PIL import Image

    png = page.input_after_label(label).screenshot()
    grey = np.asarray(Image.open(io.BytesIO(png)).convert("L"), np.float64)
    return 255.0 - grey[3:-3, 3:-3]


def assert_hidden_beside_shown(page, hidden: str, shown: str) -> None:
    """The same text typed in two fields: the hidden one must not look like the shown one.

    Compared through what survives the fields' sub-pixel offsets: where along
    the field the ink is (column profiles), and how tall the text is (dots are
    short, letters are not).
    """
    page.fill(shown, SECRET)
    page.fill(hidden, SECRET)
    page.p.evaluate("document.activeElement && document.activeElement.blur()")
    assert page.input_after_label(hidden).input_value() == SECRET  # still typed, only hidden
    assert text_security(page, hidden) == "disc"
    assert text_security(page, shown) == "none"
    plain, masked = field_ink(page, shown), field_ink(page, hidden)
    assert plain.shape == masked.shape, "the two fields should be the same size"
    alike = np.corrcoef(plain.sum(axis=0), masked.sum(axis=0))[0, 1]
    assert alike < 0.8, f"{hidden!r} shows the text as {shown!r} does (correlation {alike:.2f})"
    tall = (plain > 80).any(axis=1).sum()
    short = (masked > 80).any(axis=1).sum()
    assert 0 < short < 0.6 * tall, f"{hidden!r}: {short} rows of ink, {shown!r}: {tall}"


def test_password_is_shown_as_dots(open_page, viewer: WebViewer) -> None:
    page = open_page()
    page.fill("Address", "127.0.0.1")
    page.open_login()
    assert_hidden_beside_shown(page, "Password", "User")
    assert text_security(page, "Address") == "none"
    page.screenshot("password-typed")

    page.fill("User", "root")
    page.fill("Password", "root-pw")  # masked, and still what the server receives
    page.click("Log in")
    page.tab("lab@127.0.0.1").first.click()
    page.p.get_by_text("Administration", exact=True).click()
    page.button("Set password").wait_for()
    assert_hidden_beside_shown(page, "New password", "Account")
    for other in ("Private message", "Reason", "Server name"):
        assert text_security(page, other) == "none", f"{other!r} must stay readable"
    page.screenshot("admin-new-password")
