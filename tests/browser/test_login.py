"""Log in through the page; a wrong password says so in plain words; passwords show as dots."""

from __future__ import annotations

from playwright.sync_api import expect

from tests.browser.conftest import wait_until
from viewers.web.app import WebViewer


def test_login_and_wrong_password(open_page, viewer: WebViewer) -> None:
    page = open_page()
    said: list[str] = []
    page.p.on("console", lambda message: said.append(message.text))
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
    # No update for a component the page no longer has (the issue saw four after a join).
    assert not [m for m in said if "non-existent component" in m], said


SECRET = "hunter2-secret"

# Every input event in the page, with what the field was at that moment (the DOM says
# whether text is drawn readable: a password input, or a text-security mask).
RECORD_JS = """() => {
  const listening = Array.isArray(window.__typed);
  window.__typed = [];
  if (listening) return;
  document.addEventListener('input', (e) => {
    const t = e.target;
    window.__typed.push({el: t, type: t.getAttribute('type'),
                         sec: getComputedStyle(t).webkitTextSecurity,
                         n: (t.value || '').length});
  }, true);
}"""
STATES_JS = "el => window.__typed.filter(r => r.el === el).map(r => [r.type, r.sec, r.n])"


def assert_typed_hidden(page, label: str) -> None:
    """Typed key by key, the field was a password input at every keystroke."""
    box = page.input_after_label(label)
    expect(box).to_have_attribute("type", "password", timeout=10_000)
    assert box.get_attribute("autocomplete") == "current-password"
    page.p.evaluate(RECORD_JS)
    box.click()
    box.press_sequentially(SECRET)
    assert box.input_value() == SECRET  # still typed, only hidden
    states = box.evaluate(STATES_JS)
    assert [n for _, _, n in states] == list(range(1, len(SECRET) + 1))
    assert all(kind == "password" and mask == "disc" for kind, mask, _ in states), states


def assert_readable(page, label: str) -> None:
    box = page.input_after_label(label)
    kind, mask = box.evaluate("e => [e.type, getComputedStyle(e).webkitTextSecurity]")
    assert (kind, mask) == ("text", "none"), f"{label!r} must stay readable"


def test_password_is_a_password_input_at_every_keystroke(open_page, viewer: WebViewer) -> None:
    page = open_page()
    page.fill("Address", "127.0.0.1")
    page.open_login()
    assert_typed_hidden(page, "Password")
    assert_readable(page, "User")
    assert_readable(page, "Address")
    page.screenshot("password-typed")

    # Enter in the password field logs in, with the password typed (the server got it).
    page.fill("User", "root")
    page.fill("Password", "root-pw")
    page.input_after_label("Password").press("Enter")
    expect(page.tab("lab@127.0.0.1").first).to_have_attribute(
        "aria-selected", "true", timeout=15_000
    )
    page.p.get_by_text("Administration", exact=True).click()
    page.button("Set password").wait_for()
    assert_typed_hidden(page, "New password")
    for other in ("Account", "Private message", "Reason", "Server name"):
        assert_readable(page, other)
    page.screenshot("admin-new-password")


def test_a_student_sets_their_own_password(open_page, viewer: WebViewer) -> None:
    """A class's first password comes on a paper slip: the student replaces it in the page."""
    page = open_page()
    page.log_in("wart://127.0.0.1:7447/lab", "ben", "ben-pw")
    page.wait_text("Logged in as")
    page.p.get_by_text("My account", exact=True).first.click()  # the folder opens
    page.fill("My new password", "short")
    page.click("Set my password")
    page.wait_text("Refused: a password needs at least 8 characters")
    new_box = page.input_after_label("My new password")
    assert new_box.input_value() == ""  # never left on screen
    page.fill("My new password", "ben-new-password")
    page.click("Set my password")
    page.wait_text("Your password is changed")
    page.click("Log out")
    page.log_in("wart://127.0.0.1:7447/lab", "ben", "ben-pw")
    page.wait_text("wrong user name or password")  # the old one no longer opens the lab
    page.fill("Password", "ben-new-password")
    page.click("Log in")
    page.wait_text("Logged in as")
