"""Two browsers, two users, one (fake) lab: they chat with each other."""

from __future__ import annotations

from tests.browser.conftest import wait_until
from viewers.web.app import WebViewer


def test_two_sessions_chat(open_page, viewer: WebViewer) -> None:
    ana, ben = open_page("ana"), open_page("ben")
    for page, user in ((ana, "ana"), (ben, "ben")):
        page.log_in("127.0.0.1/lab", user, f"{user}-pw")
        page.tab("lab@127.0.0.1").first.click()
        page.join_lobby()
    ana.wait_text("Members: ana, ben")

    ana.say("hello ben, can you see the arena?")
    ben.wait_text("hello ben, can you see the arena?")
    ben.say("yes <b>clearly</b>")
    ana.wait_text("yes <b>clearly</b>")  # shown literally: no HTML from other people
    ana.screenshot("chat")
    ben.screenshot("chat")

    # ana may kick (instructor); ben's tab closes and he is told.
    ana.p.get_by_role("combobox").last.wait_for()
    ana.click("Kick")
    ana.wait_text("ben was kicked by ana")
    sessions = list(viewer.sessions.values())
    bens = [s for s in sessions if any(t.connection.user == "ben" for t in s.labs.values())]
    wait_until(
        lambda: all("lobby" not in t.panels for s in bens for t in s.labs.values()),
        what="ben's lobby tab to close",
    )
