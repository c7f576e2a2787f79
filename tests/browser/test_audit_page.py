"""The admin page's bans and audit trail, in Chromium, against a real lab (issue 38).

Registry, room and engine are real processes (tests/kit/reallab.py); the
admin bans a student from the page, the student's login is refused with the
reason, and the audit list on the page shows the ban, a kick and a grant.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from common.lab_errors import Banned
from tests.browser.test_real_lab import log_in
from tests.kit.reallab import RealLab, real_lab
from viewers.web.viser_fast import browser_address

pytestmark = pytest.mark.real_lab


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RealLab]:
    with real_lab(Path(tmp_path_factory.mktemp("auditlab"))) as env:
        yield env


def test_an_admin_bans_from_the_page_and_reads_the_audit_trail(open_page, lab: RealLab) -> None:
    with lab.lab.client("admin") as admin:
        admin.grant("alice", "kick", "ctx/lobby")
        admin.kick_from_server("bob", "answers shared in the chat")
    page = open_page("admin")
    log_in(page, lab, "admin")
    page.p.get_by_text("Administration").first.click()
    # A ban from the page: carol is refused at login with the reason and the end.
    page.fill("Account", "carol")
    page.fill("Reason", "exam week: lab closed to her")
    page.fill("Ban for (hours; empty: until lifted)", "24")
    page.click("Ban")
    page.wait_text("carol banned until")
    with lab.lab.client() as carol, pytest.raises(Banned, match="exam week") as refused:
        carol.login("carol", "correct horse")
    assert "UTC" in str(refused.value)
    # ...and on the page, in words.
    banned = open_page("carol")
    banned.log_in(lab.url, "carol", "correct horse")
    banned.wait_text("you are banned until")
    banned.wait_text("exam week: lab closed to her")
    banned.screenshot("banned")
    # What the viewer would vouch for at this page's login: its socket's peer address.
    addresses = {browser_address(b.client) for b in list(lab.viewer.sessions.values())}
    assert "127.0.0.1" in addresses
    # The audit list: everything the admin did, then only the bans.
    page.p.get_by_text("Audit trail").first.click()
    page.fill("Who (account)", "admin")
    page.click("Show audit trail")
    page.wait_text("answers shared in the chat")  # the kick, with its reason
    page.wait_text("kick in ctx/lobby")  # the grant
    page.screenshot("audit-all")
    page.fill("Action (kick, ban, grant, estop...)", "ban")
    page.click("Show audit trail")
    page.p.get_by_text("kick in ctx/lobby").first.wait_for(state="detached", timeout=10_000)
    table = page.p.get_by_role("table").last.inner_text()
    assert "exam week: lab closed to her" in table and "carol" in table
    assert "answers shared" not in table and "zenoh:" in table  # the session it came from
    page.screenshot("audit-bans")
