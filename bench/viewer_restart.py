"""A class's pages across a viewer restart: how long until each is back, and what survived.

A real lab (router, registry, room, engine, runner, the agent context ``arena``) and
its web viewer as real processes. ``--pages`` Chromium pages (Debian's, Playwright),
each its own browser profile, log in as the lab's four test accounts in turn and
join the arena; the first four start a controller on a robot each and type a line
after Run that they never save. Then the viewer process is stopped with SIGTERM (an
upgrade, a supervisor's restart) or, with ``--kill``, killed with SIGKILL (a crash:
nothing written at its end, the pages come back as the viewer last noted them, so
the bench waits a note's period after the typing), and a new one starts on the same
port and data directory. Printed:

- how long the old viewer took to exit, and the new one to serve (its token up);
- per page, from the signal to the page saying "the web viewer restarted" with its
  arena open again: min, median, max;
- the runs the pages show still going, and the editors whose unsaved line came back.

    python -m bench.viewer_restart [--pages 8] [--kill]
"""

from __future__ import annotations

import dataclasses
import signal
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import cli as bench_cli
from services.lab.wiring import viewer_spec
from tests.kit.lab import PASSWORD, USERS
from tests.kit.procs import free_port
from tests.kit.reallab import CTX, real_lab
from viewers.web.handover import JOURNAL_PERIOD_S
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
# Each page notes, by its own clock, when it first says it is back in its arena: the
# bench asking each page in turn for its text lagged behind eight busy pages.
WATCH_BACK = """back => {
  window.wartBackAt = 0;
  const id = setInterval(() => {
    const text = document.body.textContent;
    if (text.includes(back) && text.includes("Upload controller")) {
      window.wartBackAt = Date.now();
      clearInterval(id);
    }
  }, 50);
}"""


def editor_text(page: Any) -> str:
    return str(page.p.evaluate("() => window.wartEditor.editorFor(null).view.state.doc.toString()"))


def put_code(page: Any, text: str) -> None:
    """The editor's text, as a paste puts it."""
    page.p.get_by_role("textbox", name="Controller code", exact=True).wait_for(timeout=15_000)
    page.p.evaluate(
        "text => { const v = window.wartEditor.editorFor(null).view;"
        " v.dispatch({changes: {from: 0, to: v.state.doc.length, insert: text}}); }",
        text,
    )


def start_run(page: Any, robot: str) -> None:
    """Run the ticking controller on ``robot``, then type a line that is never saved."""
    put_code(page, TICKING)
    page.input_after_label("Run on").click()
    page.p.get_by_role("option", name=robot, exact=True).click()
    page.click("Run in simulation")
    page.wait_text(f"Your controller runs on {robot}", timeout=30_000)
    put_code(page, UNSAVED)


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("viewer_restart", __doc__)
    p.add_argument("--pages", type=int, default=8, help="browser pages, 1 to 40 (default 8)")
    p.add_argument("--kill", action="store_true", help="kill the viewer (SIGKILL), not stop it")
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
        spec = viewer_spec(lab.lab.wiring(), "restarting", http_port=free_port())
        argv = list(spec.argv)
        argv[argv.index("--data-dir") + 1] = str(Path(tmp) / "restarting-viewer")
        spec = dataclasses.replace(spec, argv=argv)
        viewer = lab.lab.start(spec, name="viewer-before")
        url = f"http://127.0.0.1:{argv[argv.index('--http-port') + 1]}"
        browser = launch_chromium(pw)
        pages: list[Any] = []
        for i in range(args.pages):
            user = users[i % len(users)]
            page = ViserPage(new_test_context(browser).new_page(), f"restart-{i}")  # type: ignore[attr-defined]
            page.open(url)
            page.log_in(lab.url, user, PASSWORD)
            page.tab(tab_label(lab.address)).first.click()
            page.wait_text("Logged in as", timeout=30_000)
            page.click(f"Join {CTX}", timeout=30_000)
            page.wait_text("Upload controller", timeout=30_000)
            if i < len(ROBOTS):
                start_run(page, ROBOTS[i])
            pages.append(page)
            print(f"page {i + 1}/{args.pages} in the arena as {user}", flush=True)
        runs = min(len(ROBOTS), len(pages))
        # The last typing reaches the viewer within a second; what a crash keeps is what
        # the viewer noted last, at most a note's period later.
        time.sleep(JOURNAL_PERIOD_S + 1.0 if args.kill else 1.0)
        for page in pages:
            page.p.evaluate(WATCH_BACK, BACK)
        began, signalled_at = time.monotonic(), time.time()
        viewer.popen.send_signal(signal.SIGKILL if args.kill else signal.SIGTERM)
        viewer.popen.wait(60)
        exited_s = time.monotonic() - began
        lab.lab.start(spec, name="viewer-after")
        serving_s = time.monotonic() - began
        back: dict[int, float] = {}
        deadline = time.monotonic() + 120
        while len(back) < len(pages) and time.monotonic() < deadline:
            for i, page in enumerate(pages):
                at = page.p.evaluate("() => window.wartBackAt") if i not in back else 0
                if at:
                    back[i] = at / 1000 - signalled_at
            time.sleep(0.2)
        driven = restored = 0
        for i in range(runs):
            running = f"Your controller runs on {ROBOTS[i]}"
            until = time.monotonic() + 10  # the run and the editor fill after the tab shows
            while time.monotonic() < until and not (
                running in pages[i].p.inner_text("body") and editor_text(pages[i]) == UNSAVED
            ):
                time.sleep(0.1)
            driven += running in pages[i].p.inner_text("body")
            restored += editor_text(pages[i]) == UNSAVED
        browser.close()

    how = "killed (SIGKILL)" if args.kill else "stopped (SIGTERM)"
    times = sorted(back.values())
    print(
        f"{len(pages)} pages; the old viewer {how}, exited in {exited_s:.1f} s; "
        f"the new one serving {serving_s:.1f} s after the signal"
    )
    if times:
        print(
            f"back in their arena after the signal: min {times[0]:.1f} s, "
            f"median {statistics.median(times):.1f} s, max {times[-1]:.1f} s "
            f"({len(times)} of {len(pages)})"
        )
    print(f"runs the pages show still going after the restart: {driven} of {runs}")
    print(f"editors whose unsaved line came back: {restored} of {runs}")
    return 0 if len(times) == len(pages) and driven == runs and restored == runs else 1


if __name__ == "__main__":
    raise SystemExit(main())
