"""What one viser page costs the test browser: Chromium's CPU per page opened, by process.

The browser tests open a page in a browser context of its own for each user
(tests/browser/conftest.py); on a CI machine Chromium renders in software, and
its CPU is most of what the browser tests cost. This opens ``--pages`` pages one
after the other on a demo lab's viewer (in this process), each in a new context
as the tests do, optionally logged in and joined to the arena (``--join``), keeps
each open ``--hold`` seconds, closes it, and prints Chromium's CPU seconds per
page by kind of process (browser, renderer, GPU process). ``--blank`` opens an
empty page instead: what a context and its renderer cost before any of viser's.
Extra Chromium switches (``--chromium-arg``) are added to the tests' own.

    python -m bench.page_load_cost --pages 6
    python -m bench.page_load_cost --pages 4 --join
    python -m bench.page_load_cost --pages 6 --chromium-arg=--js-flags=--no-opt
    python -m bench.page_load_cost --pages 2 --join --hold 15 --draws
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import cli as bench_cli
from bench.cpu_by_process import TICKS_PER_S, kind_of
from tests.kit.procs import free_port
from viewers.web.app import WebViewer
from viewers.web.demo_lab import DemoConnector, DemoLab


class ChromiumCpu:
    """Chromium's CPU seconds by kind of process since :meth:`start`, every process's whole
    life counted (a context's renderer ends with it: read it before the context closes)."""

    def __init__(self) -> None:
        self._before: dict[int, float] = {}
        self._seen: dict[int, tuple[str, float]] = {}

    @staticmethod
    def _chromium_processes() -> dict[int, tuple[str, float]]:
        found = {}
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            kind = kind_of(int(entry))
            if kind is None or not kind.startswith("chromium"):
                continue
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            found[int(entry)] = (kind, (int(fields[11]) + int(fields[12])) / TICKS_PER_S)
        return found

    def start(self) -> None:
        self._before = {pid: cpu for pid, (_, cpu) in self._chromium_processes().items()}
        self._seen = {}

    def sample(self) -> None:
        self._seen.update(self._chromium_processes())

    def by_kind(self) -> dict[str, float]:
        """CPU seconds by kind, most first."""
        spent: dict[str, float] = collections.defaultdict(float)
        for pid, (kind, cpu) in self._seen.items():
            spent[kind.removeprefix("chromium ")] += cpu - self._before.get(pid, 0.0)
        return dict(sorted(spent.items(), key=lambda kv: -kv[1]))


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("page_load_cost", __doc__)
    p.add_argument("--pages", type=int, default=6, help="pages opened one after another (6)")
    p.add_argument("--hold", type=float, default=1.0, help="seconds each stays open (1)")
    kind = p.add_mutually_exclusive_group()
    kind.add_argument("--join", action="store_true", help="log in and join the demo arena")
    kind.add_argument("--blank", action="store_true", help="an empty page: the context alone")
    p.add_argument(
        "--chromium-arg", action="append", default=[], help="an extra Chromium switch (repeat)"
    )
    p.add_argument(
        "--draws",
        action="store_true",
        help="let WebGL draw (the test pages skip its draw calls except for screenshots)",
    )
    args = p.parse_args(argv)
    if not 1 <= args.pages <= 100:
        p.error("--pages: give 1 to 100")
    if not 0 <= args.hold <= 60:
        p.error("--hold: give 0 to 60 seconds")

    # playwright is optional: only the page benchmarks drive a browser (the kit's
    # page helpers import it at their top)
    try:
        from playwright.sync_api import sync_playwright

        from tests.kit import pages  # the page helpers: playwright too
    except ImportError as exc:
        print(f"page_load_cost needs playwright (pip install playwright): {exc}", file=sys.stderr)
        return 2

    if not pages.CHROMIUM.exists():
        print(
            f"{pages.CHROMIUM} is missing (apt-get install chromium-headless-shell)",
            file=sys.stderr,
        )
        return 2
    pages.CHROMIUM_ARGS.extend(args.chromium_arg)
    if args.draws:
        pages.DRAW_SWITCH_SCRIPT = pages.draw_switch_script(True)
    lab = DemoLab("Test lab", robots=12)
    viewer = WebViewer(
        DemoConnector(("lab", lab)), port=free_port(), data_dir=Path(tempfile.mkdtemp())
    )
    cpu = ChromiumCpu()
    try:
        with sync_playwright() as pw:
            browser = pages.launch_chromium(pw)
            time.sleep(2.0)  # the browser's own start is not a page's
            cpu.start()
            started = time.monotonic()
            for i in range(args.pages):
                _open_one(browser, viewer, args, i, cpu)
                print(f"page {i + 1} of {args.pages}", file=sys.stderr)
            cpu.sample()
            wall = time.monotonic() - started
            browser.close()
    finally:
        viewer.stop()
        lab.close()
    spent = cpu.by_kind()
    total = sum(spent.values())
    what = "an empty page" if args.blank else "joined to the arena" if args.join else "opened"
    switches = [*args.chromium_arg, *(["drawing"] if args.draws else [])]
    extra = f" (with {' '.join(switches)})" if switches else ""
    print(
        f"{args.pages} pages {what}{extra}, {wall:.1f} s: Chromium {total:.1f} s of CPU, "
        f"{total / args.pages:.2f} s a page"
    )
    for process, seconds in spent.items():
        if seconds >= 0.05:
            print(f"  {seconds / args.pages:6.2f} s a page  {process}")
    return 0


def _open_one(
    browser: Any, viewer: Any, args: argparse.Namespace, i: int, cpu: ChromiumCpu
) -> None:
    from tests.kit import pages  # imports playwright, optional (main checked it is there)

    context: Any = pages.new_test_context(browser)
    try:
        page = context.new_page()
        if args.blank:
            page.goto("data:text/html,<p>a page</p>")
        else:
            viser_page = pages.ViserPage(page, f"page{i}")
            viser_page.open(viewer.url)
            if args.join:
                user = "ana"
                viser_page.log_in("127.0.0.1", user, f"{user}-pw")
                viser_page.tab("lab@127.0.0.1").first.click()
                viser_page.click("Join arena")
                pages.wait_until(
                    lambda: any(s.view.drawn is not None for s in list(viewer.sessions.values())),
                    60,
                    what="a frame of the arena drawn",
                )
        time.sleep(args.hold)
        cpu.sample()  # the renderer ends with its context
    finally:
        context.close()


if __name__ == "__main__":
    sys.exit(main())
