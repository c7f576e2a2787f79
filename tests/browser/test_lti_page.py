"""An LTI launch in Chromium (issue 36): the LMS's link opens the lab's page logged in.

The browser goes where an LMS sends it: the tool's login URL, the (fake)
platform's auth page, whose form posts the signed launch back to the tool,
which sets the page's saved-login cookie and sends the browser to the page; the
page then logs in with it, as after a reload, without a password.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlencode

import pytest

from tests.browser.conftest import ViserPage, new_test_context, page_url
from tests.browser.test_real_lab import online
from tests.kit.courses import COURSE
from tests.kit.lti_platform import CLIENT_ID, DEPLOYMENT, FakePlatform, Launcher
from tests.kit.lti_tool import start_lti
from tests.kit.procs import wart
from tests.kit.reallab import RealLab, real_lab
from viewers.web.tabs import tab_label


@pytest.fixture(scope="module")
def lti_lab(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[tuple[RealLab, FakePlatform, str]]:
    tmp = Path(tmp_path_factory.mktemp("ltipage"))
    with real_lab(tmp) as lab:
        roster = tmp / "class.csv"
        roster.write_text("user,name,role\nida,Ida I,teacher\n")
        done = wart(
            "users", "--db", str(lab.lab.db_path), "import", str(roster), "--course", COURSE
        )
        assert done.returncode == 0, done.stderr
        platform = FakePlatform()
        try:
            tool = start_lti(
                lab.lab, tmp, platform, page=page_url(lab.viewer.url), lab_address=lab.url
            )
            yield lab, platform, tool
        finally:
            platform.close()


def test_a_launch_from_the_lms_opens_the_page_logged_in(
    chromium: object, lti_lab: tuple[RealLab, FakePlatform, str]
) -> None:
    lab, platform, tool = lti_lab
    platform.next = Launcher(sub="u-31", name="Lina Launch")
    context = new_test_context(chromium)
    try:
        page = context.new_page()  # type: ignore[attr-defined]
        vp = ViserPage(page, "lti-launch")
        query = urlencode(
            {
                "iss": platform.url,
                "login_hint": "h",
                "target_link_uri": f"{tool}/lti/launch",
                "client_id": CLIENT_ID,
                "lti_deployment_id": DEPLOYMENT,
            }
        )
        page.goto(f"{tool}/lti/login?{query}")  # the LMS's link
        vp.wait_ready(timeout=30_000)
        assert page.url.startswith(lab.viewer.url.replace("localhost", "127.0.0.1"))
        vp.tab(tab_label(lab.address)).first.click(timeout=30_000)
        vp.wait_text("Logged in as", timeout=30_000)
        assert vp.button("Log in").count() == 0
        users = [u for u in online(lab) if u.startswith("lms-")]
        assert len(users) == 1, online(lab)
        vp.screenshot("launched")
    finally:
        context.close()  # type: ignore[attr-defined]
