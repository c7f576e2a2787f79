"""Real-browser fixtures: Debian's Chromium driven by Playwright, a viewer on the demo lab.

The browser's settings and the page helpers are the kit's (tests/kit/pages.py,
re-exported here for the tests that import them from this file). Screenshots go
to test-artifacts/ and are kept as artefacts of the run.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.kit.pages import (
    CANVAS_AT_JS,
    CHROMIUM,
    CHROMIUM_ARGS,
    FRAME_CAP_HZ,
    TEST_PAGE_DPR,
    VIEWPORT,
    ViserPage,
    describe_view,
    join_demo_arena,
    launch_chromium,
    new_test_context,
    page_url,
    screen_points,
    settle,
    show_still_frame,
    wait_for_aimed_camera,
    wait_until,
)
from tests.kit.procs import free_port
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoConnector, DemoLab

pytestmark = pytest.mark.browser


def _skip_reason() -> str | None:
    if not CHROMIUM.exists():
        return f"{CHROMIUM} is missing (apt-get install chromium-headless-shell)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is missing (pip install playwright)"
    return None


@pytest.fixture(scope="session")
def chromium() -> Iterator[object]:
    reason = _skip_reason()
    if reason:
        pytest.skip(reason)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = launch_chromium(pw)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture
def fake_lab() -> Iterator[DemoLab]:
    lab = DemoLab("Test lab", robots=12)
    yield lab
    lab.close()


@pytest.fixture
def viewer(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[WebViewer]:
    """The viewer open_page opens: the demo lab's; in a module marked ``real_lab``, the
    viewer of the module's ``lab`` fixture (a RealLab, tests/kit/reallab.py)."""
    if request.node.get_closest_marker("real_lab") is not None:
        yield request.getfixturevalue("lab").viewer
        return
    fake_lab: DemoLab = request.getfixturevalue("fake_lab")
    app = WebViewer(
        DemoConnector(("lab", fake_lab)),
        port=free_port(),
        data_dir=tmp_path / "viewer",
    )
    yield app
    app.stop()


CALL_FAILED = pytest.StashKey[bool]()


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):
    """Note a test's failure on its item, so its fixtures can keep what the pages showed."""
    report = yield
    if report.when == "call" and report.failed:
        item.stash[CALL_FAILED] = True
    return report


@pytest.fixture(autouse=True, scope="session")
def viewer_log_at_info() -> Iterator[None]:
    """The viewer runs in the test's process: its INFO lines (a join asked, answered,
    failed) go into a failed test's captured log, where they say what the server did."""
    viewer_log = logging.getLogger("wart.viewer")
    level = viewer_log.level
    viewer_log.setLevel(logging.INFO)
    yield
    viewer_log.setLevel(level)


@pytest.fixture
def open_page(chromium: object, viewer: WebViewer, request: pytest.FixtureRequest):
    """Open the viewer in a new browser context (its own cookies and storage).

    A failed test leaves a screenshot of each of its pages (test-artifacts/, named
    ``...-at-failure.png``): what the student would have seen when it failed.
    """
    contexts: list[object] = []
    pages: list[ViserPage] = []

    def opener(tag: str = "a", init: str | None = None) -> ViserPage:
        """``init``: a script every page of the context runs before the page's own."""
        context = new_test_context(chromium)
        if init is not None:
            context.add_init_script(init)  # type: ignore[attr-defined]
        contexts.append(context)
        page = context.new_page()  # type: ignore[attr-defined]
        vp = ViserPage(page, f"{request.node.name}-{tag}")  # before the page opens its socket
        pages.append(vp)
        vp.open(viewer.url)
        return vp

    yield opener
    if request.node.stash.get(CALL_FAILED, False):
        for vp in pages:
            try:
                vp.screenshot("at-failure")
            except Exception as exc:  # a page already gone: the others still count
                warnings.warn(f"no screenshot of {vp.name} at the failure: {exc}", stacklevel=1)
    for context in contexts:
        context.close()  # type: ignore[attr-defined]


__all__ = [
    "CANVAS_AT_JS",
    "CHROMIUM",
    "CHROMIUM_ARGS",
    "FRAME_CAP_HZ",
    "TEST_PAGE_DPR",
    "VIEWPORT",
    "ViserPage",
    "describe_view",
    "join_demo_arena",
    "new_test_context",
    "page_url",
    "screen_points",
    "settle",
    "show_still_frame",
    "wait_for_aimed_camera",
    "wait_until",
]
