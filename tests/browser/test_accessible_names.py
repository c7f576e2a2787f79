"""The page's inputs carry accessible names: Playwright's get_by_label finds them.

viser 1.1.1's labels point at ids its text inputs do not have; viewers/web/labels.py
links each label to its input with aria-labelledby. The login form, the code
editor and the robot list are used here through their names alone, and the
login form by keyboard (Tab from User to Password).
"""

from __future__ import annotations

from tests.browser.conftest import wait_until
from viewers.web.app import WebViewer


def test_inputs_are_found_by_their_labels(open_page, viewer: WebViewer) -> None:
    page = open_page("ana")
    p = page.p
    address = p.get_by_label("Address", exact=True)
    address.fill("127.0.0.1")
    address.press("Enter")
    page.open_login()

    user = p.get_by_label("User", exact=True)
    user.fill("ana")
    user.press("Tab")  # the keyboard reaches the password next
    password = p.get_by_label("Password", exact=True)
    assert password.evaluate("el => el === document.activeElement")
    p.keyboard.type("ana-pw")
    page.screenshot("named-login")
    password.press("Enter")  # Enter logs in
    page.tab("lab@127.0.0.1").first.click()
    page.click("Join arena")
    page.tab("arena").last.click()

    # The code editor (CodeMirror) is a textbox named "Controller code".
    code = p.get_by_role("textbox", name="Controller code", exact=True)
    code.wait_for(timeout=10_000)
    session = next(iter(viewer.sessions.values()))
    text = "# typed into the box named Controller code"
    code.click()
    p.keyboard.press("Control+a")
    p.keyboard.type(text)
    # The page shows the panel's widgets while the panel is still being registered.
    wait_until(lambda: any(lab.panels for lab in session.labs.values()), what="the arena's panel")
    panel = next(tab for lab in session.labs.values() for tab in lab.panels.values())
    bench = panel.workbench
    assert bench is not None
    wait_until(lambda: bench.code.value == text, what="the Code box's text on the server")
    # Dropdowns are named too: the robot list is a combobox called "Robot".
    assert p.get_by_role("combobox", name="Robot", exact=True).count() == 1
    page.screenshot("named-code")
