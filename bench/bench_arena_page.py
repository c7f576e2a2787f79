"""A real arena in the page: how late the video and the robot's pose reach a browser.

A real lab (router, registry, room, engine) and the arena `wart up` runs without
hardware (an emulated Khepera with slipping wheels behind a bridge, a synthetic
camera over it) as real processes; the viewer in this process; one Chromium page
(Debian's, Playwright) logged in and watching the arena while the robot drives
circles. Printed, over ``--seconds``:

- frame captured -> sent to the browser: the camera's capture time to the moment
  the viewer hands the floor frame to the browser's socket (the page then paints
  it on its next animation frame);
- pose change -> sent to the browser: each pose the viewer sends is matched to the
  emulator's true trajectory (written 30 times a second with its time); the lag is
  the send time minus the true time of the nearest true pose;
- and the drawn robot's distance from the truth at send time.

    python -m bench.bench_arena_page [--seconds 30]
"""

from __future__ import annotations

import math
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench import cli as bench_cli
from common.tracking.truth import TruthError, read_truth
from tests.kit.lab import PASSWORD
from tests.kit.reallab import real_lab

REAL = "real1"


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("bench_arena_page", __doc__)
    p.add_argument("--seconds", type=float, default=30.0, help="driving time measured (default 30)")
    args = p.parse_args(argv)

    # playwright is optional: only the page benchmarks drive a browser (the kit's
    # page helpers import it at their top)
    from playwright.sync_api import sync_playwright

    from tests.kit.pages import ViserPage, launch_chromium, new_test_context

    with tempfile.TemporaryDirectory(prefix="wart-bench-arena-") as tmp, real_lab(
        Path(tmp), real_arena=REAL
    ) as lab, sync_playwright() as pw:  # fmt: skip
        browser = launch_chromium(pw)
        context: Any = new_test_context(browser)
        page = ViserPage(context.new_page(), "bench")
        page.open(lab.viewer.url)
        page.log_in(lab.url, "ida", PASSWORD)
        page.tab(lab.address.label).first.click()
        page.wait_text("Logged in as")
        page.click(f"Join {REAL}")
        session = next(iter(lab.viewer.sessions.values()))
        view, video = session.view, session.video
        truth_path = lab.lab.wiring().state_dir / "dev" / f"{REAL}-truth.json"
        deadline = time.monotonic() + 90
        while video.shown < 0 or view.drawn is None:
            if time.monotonic() > deadline:
                raise SystemExit("the arena's video never reached the browser")
            page.p.wait_for_timeout(100)

        truth: list[tuple[float, float, float]] = []  # (true at, x, y)
        sent: list[tuple[float, float, float]] = []  # (sent at, x, y)
        stop = threading.Event()

        def sample() -> None:
            last_seq = -1
            while not stop.is_set():
                try:
                    t = read_truth(truth_path)
                    if not truth or t.at != truth[-1][0]:
                        x, y, _ = t.robots["k1"]
                        truth.append((t.at, x, y))
                except (TruthError, KeyError):
                    pass
                drawn = view.drawn
                if drawn is not None and drawn.frame.seq != last_seq:
                    last_seq = drawn.frame.seq
                    x, y, _ = drawn.positions[0]
                    sent.append((time.time(), float(x) * 1000, float(y) * 1000))
                stop.wait(0.005)

        video.delays.clear()
        thread = threading.Thread(target=sample, daemon=True)
        thread.start()
        with lab.driving("k1", speeds=(8, 12), world=REAL):
            page.p.wait_for_timeout(args.seconds * 1000)
        stop.set()
        thread.join(2)
        browser.close()

    video_ms = np.array(video.delays) * 1000
    true_t = np.array([s[0] for s in truth])
    true_xy = np.array([s[1:] for s in truth])
    lags, errors = [], []
    for at, x, y in sent:
        window = (true_t <= at) & (true_t > at - 2.0)
        if window.sum() < 2:
            continue
        d = np.hypot(true_xy[window, 0] - x, true_xy[window, 1] - y)
        lags.append((at - true_t[window][int(np.argmin(d))]) * 1000)
        latest = np.flatnonzero(true_t <= at)[-1]
        errors.append(math.hypot(true_xy[latest, 0] - x, true_xy[latest, 1] - y))
    print(f"{len(video_ms)} video frames sent to the browser in {args.seconds:g} s of driving")
    print(
        f"frame captured -> sent to the browser: p50 {np.percentile(video_ms, 50):.0f} ms, "
        f"p99 {np.percentile(video_ms, 99):.0f} ms"
    )
    print(
        f"pose change -> sent to the browser: p50 {np.percentile(lags, 50):.0f} ms, "
        f"p99 {np.percentile(lags, 99):.0f} ms ({len(lags)} poses)"
    )
    print(
        f"robot drawn vs true pose at send: p50 {np.percentile(errors, 50):.1f} mm, "
        f"p99 {np.percentile(errors, 99):.1f} mm"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
