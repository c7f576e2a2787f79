"""A class's pages across a viewer restart: how long until each is back, and what survived.

A real lab (router, registry, room, engine, runner, the agent context ``arena``) as
real processes; the viewer in this process. ``--pages`` Chromium pages (Debian's,
Playwright), each its own browser profile, log in as the lab's four test accounts
in turn and join the arena; the first four start a controller on a robot each and
type a line after Run that they never save. Then the viewer stops as SIGTERM stops
it, and a new one starts on the same port and data directory. Printed:

- how long the old viewer's stop took (viser waits for its pages' sockets to close);
- per page, from the stop to the page saying "the web viewer restarted" with its
  arena open again: min, median, max;
- the runs still going after the restart, and the editors whose unsaved line came back.

    python -m bench.viewer_restart [--pages 8]
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import cli as bench_cli
from tests.kit.lab import PASSWORD, USERS
from tests.kit.reallab import CTX, RealLab, real_lab
from tests.kit.waits import wait_for
from viewers.web.app import WebViewer
from viewers.web.chat_panel import ChatPanel
from viewers.web.connector import LiveConnector
from viewers.web.tabs import tab_label

TICKING = """\
from common.controller import Controller, Khepera


class Ticking(Controller):
    period = 0.05

    def do_work(self, robot: Khepera) -> None:
        robot.set_speeds(2, 2)
"""
UNSAVED = TICKING + "# typed after Run, never saved\n"
ROBOTS = ("k0", "k1", "k2", "k3")
BACK = "the web viewer restarted"


def panel_of(lab: RealLab, user: str, page_no: int) -> ChatPanel:
    """The arena panel of ``user``'s ``page_no``-th page (sessions in connection order)."""
    mine = [
        s
        for _, s in sorted(lab.viewer.sessions.items())
        if any(t.connection.user == user for t in s.labs.values())
    ]
    panels = next(iter(mine[page_no].labs.values())).panels
    wait_for(lambda: CTX in panels, 15, what=f"{user}'s arena panel")
    return panels[CTX]


def put_code(page: Any, text: str) -> None:
    """The editor's text, as a paste puts it."""
    page.p.get_by_role("textbox", name="Controller code", exact=True).wait_for(timeout=15_000)
    page.p.evaluate(
        "text => { const v = window.wartEditor.editorFor(null).view;"
        " v.dispatch({changes: {from: 0, to: v.state.doc.length, insert: text}}); }",
        text,
    )


def start_run(page: Any, panel: ChatPanel, robot: str) -> None:
    """Run the ticking controller on ``robot``, then type a line that is never saved."""
    bench = panel.workbench
    assert bench is not None
    put_code(page, TICKING)
    wait_for(lambda: bench.code.value == TICKING, 10, what="the code on the server")
    page.input_after_label("Run on").click()
    page.p.get_by_role("option", name=robot, exact=True).click()
    wait_for(lambda: bench.target.value == robot, 10, what=f"{robot} chosen")
    page.click("Run in simulation")
    page.wait_text(f"Your controller runs on {robot}", timeout=30_000)
    put_code(page, UNSAVED)
    wait_for(lambda: bench.code.value == UNSAVED, 10, what="the unsaved line on the server")


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("viewer_restart", __doc__)
    p.add_argument("--pages", type=int, default=8, help="browser pages, 1 to 40 (default 8)")
    args = p.parse_args(argv)
    if not 1 <= args.pages <= 40:
        p.error("--pages must be 1..40")

    # playwright is optional: only the page benchmarks drive a browser
    from playwright.sync_api import sync_playwright

    from tests.kit.pages import ViserPage, launch_chromium, new_test_context

    users = list(USERS)
    with tempfile.TemporaryDirectory(prefix="wart-bench-restart-") as tmp, real_lab(
        Path(tmp), agents=True, slot=600.0
    ) as lab, sync_playwright() as pw:  # fmt: skip
        browser = launch_chromium(pw)
        pages: list[Any] = []
        seen: dict[str, int] = {}
        for i in range(args.pages):
            user = users[i % len(users)]
            page = ViserPage(new_test_context(browser).new_page(), f"restart-{i}")  # type: ignore[attr-defined]
            page.open(lab.viewer.url)
            page.log_in(lab.url, user, PASSWORD)
            page.tab(tab_label(lab.address)).first.click()
            page.wait_text("Logged in as", timeout=30_000)
            page.click(f"Join {CTX}", timeout=30_000)
            page.wait_text("Upload controller", timeout=30_000)
            panel = panel_of(lab, user, seen.get(user, 0))
            seen[user] = seen.get(user, 0) + 1
            if i < len(ROBOTS):
                start_run(page, panel, ROBOTS[i])
            pages.append(page)
            print(f"page {i + 1}/{args.pages} in the arena as {user}", flush=True)

        old, port = lab.viewer, lab.viewer.port
        book = old.handovers.path
        assert book is not None
        began = time.monotonic()
        old.stop()
        stopped_s = time.monotonic() - began
        lab.connector.close()
        lab.connector = LiveConnector(
            lab.session, lab.address, lab.lab.key_hex, data_dir=book.parent
        )
        lab.viewer = WebViewer(
            lab.connector, port=port, default_address=lab.address, data_dir=book.parent
        )
        back: dict[int, float] = {}
        deadline = time.monotonic() + 120
        while len(back) < len(pages) and time.monotonic() < deadline:
            for i, page in enumerate(pages):
                if i not in back:
                    body = page.p.inner_text("body")
                    if BACK in body and "Upload controller" in body:
                        back[i] = time.monotonic() - began
            time.sleep(0.1)
        runs = min(len(ROBOTS), len(pages))
        driven = 0
        restored = 0
        for i in range(min(len(ROBOTS), len(pages))):
            text = pages[i].p.evaluate(
                "() => window.wartEditor.editorFor(null).view.state.doc.toString()"
            )
            restored += text == UNSAVED
        session = next(iter(lab.viewer.sessions.values()), None)
        for tab in session.labs.values() if session is not None else ():
            robots = tab.panels[CTX].robots if CTX in tab.panels else None
            if robots is not None:  # its table fills as the arena's news comes in
                until = time.monotonic() + 15
                while sum(map(robots.driven, ROBOTS)) < runs and time.monotonic() < until:
                    time.sleep(0.1)
                driven = sum(map(robots.driven, ROBOTS))
        browser.close()

    times = sorted(back.values())
    print(f"{len(pages)} pages; the old viewer's stop took {stopped_s:.1f} s")
    if times:
        print(
            f"back in their arena after the stop: min {times[0]:.1f} s, "
            f"median {statistics.median(times):.1f} s, max {times[-1]:.1f} s "
            f"({len(times)} of {len(pages)})"
        )
    print(f"runs still going after the restart: {driven} of {runs}")
    print(f"editors whose unsaved line came back: {restored} of {runs}")
    return 0 if len(times) == len(pages) and driven == runs and restored == runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
