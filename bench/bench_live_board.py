"""The page's live leaderboard: how late a stored score shows in a browser's DOM.

A real lab as processes (router, registry, engine, runner, the agent context
``arena``, the grader), a course of ``--students`` imported (their first
passwords from the import), and an assignment on the empty map (1 episode of 2
simulated s). alice (in the course) has the arena's Course folder open in
Chromium with the assignment chosen; nobody clicks after that. The students
submit tests/integration/grading/works.py one every ``--gap`` s (so the
grader is not a queue: this measures the publication, not the grading). For
each, the delay is the score stored (the submission's ``graded_at``, written by
the grader) to the moment the student's name appears in a leaderboard cell of
alice's page (a MutationObserver's ``Date.now()``; one machine, one clock).

    .venv/bin/python -m bench.bench_live_board --students 12 --gap 4
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench import cli as bench_cli
from bench.bench_grading import pct
from common.client.grader_client import GraderClient
from common.client.lab_client import LabClient
from services.grader.assignment import parse_assignment
from services.grader.grading_db import GradingStore
from services.registry.accounts_db import RegistryDB
from services.registry.courses_db import CourseStore
from services.registry.roster import RosterRow
from tests.kit.courses import assignment_toml
from tests.kit.lab import PASSWORD
from tests.kit.reallab import CTX, real_lab

REPO = Path(__file__).resolve().parent.parent

# Every cell's text seen for the first time, with the browser's clock (ms since the epoch).
OBSERVER_JS = """
(names) => {
  window.__seen = {};
  const wanted = new Set(names);
  const look = () => {
    for (const td of document.querySelectorAll('td')) {
      const t = td.textContent.trim();
      if (wanted.has(t) && !(t in window.__seen)) window.__seen[t] = Date.now();
    }
  };
  new MutationObserver(look).observe(document.body,
    { childList: true, subtree: true, characterData: true });
  look();
}
"""


def main(argv: list[str] | None = None) -> int:
    p = bench_cli.parser("bench_live_board", __doc__)
    p.add_argument("--students", type=int, default=12)
    p.add_argument("--gap", type=float, default=4.0, help="s between two submissions")
    args = p.parse_args(argv)

    # playwright is optional: only the page benchmarks drive a browser (the kit's
    # page helpers import it at their top)
    from playwright.sync_api import sync_playwright

    from tests.kit.pages import ViserPage, launch_chromium, new_test_context

    students = [f"s{i:03d}" for i in range(args.students)]
    names = {s: f"Student {i:03d}" for i, s in enumerate(students)}
    source = (REPO / "tests" / "integration" / "grading" / "works.py").read_bytes()
    with tempfile.TemporaryDirectory(prefix="bench-board-") as tmp, real_lab(
        Path(tmp), agents=True
    ) as lab, sync_playwright() as pw:  # fmt: skip
        db = RegistryDB(lab.lab.db_path)
        rows = [RosterRow(line=2, user="alice", name="Alice A")]
        rows += [RosterRow(line=n + 3, user=s, name=names[s]) for n, s in enumerate(students)]
        report = CourseStore(db).import_roster("robotics-26", rows)
        text = assignment_toml("board", episodes="1", seeds="[4]", time_limit="2.0", quota="100")
        assignment, map_text = parse_assignment(text.encode(), "a.toml", REPO / "maps")
        store = GradingStore(db.database)
        store.put_assignment(assignment, map_text)
        lab.lab.start_grader()

        browser = launch_chromium(pw)
        context: Any = new_test_context(browser)
        page = ViserPage(context.new_page(), "bench")
        page.open(lab.viewer.url)
        page.log_in(lab.url, "alice", PASSWORD)  # into the arena, as tests/browser do
        page.tab(lab.address.label).first.click()
        page.click(f"Join {CTX}", timeout=15_000)
        page.tab(f"{CTX} (arena)").last.click()
        page.wait_text("Upload controller")
        page.p.get_by_text("Course", exact=True).first.click()
        page.click("Refresh assignments")
        page.wait_text("1 assignment(s) in your courses.")
        page.input_after_label("Assignment").click()
        page.p.get_by_role("option", name="board", exact=True).click()
        page.click("Leaderboard")
        page.wait_text("No graded submission yet.")
        page.p.evaluate(OBSERVER_JS, list(names.values()))

        clients = []
        for s in students:  # logins first (argon2id), with the import's first passwords
            client = LabClient(lab.session, lab.lab.realm, lab.lab.identity.verify_key,
                               presence=False)  # fmt: skip
            client.login(s, report.passwords[s])
            clients.append(client)
        print(f"{len(students)} students logged in; one submits every {args.gap:g} s", flush=True)
        subs: dict[str, str] = {}
        for s, client in zip(students, clients, strict=True):
            subs[s] = GraderClient(client).submit("board", source, "works.py").submission
            time.sleep(args.gap)
        deadline = time.monotonic() + 120
        seen: dict[str, float] = {}
        while time.monotonic() < deadline:
            seen = json.loads(page.p.evaluate("JSON.stringify(window.__seen)"))
            if len(seen) == len(students):
                break
            time.sleep(0.5)
        for client in clients:
            client.close()
        graded = {s: store.submissions("board", s, subs[s])[0] for s in students}
        db.close()
        browser.close()

    delays, missing = [], []
    for s in students:
        info = graded[s]
        if info.graded_at is None or names[s] not in seen:
            missing.append(f"{s} ({info.status})")
            continue
        delays.append(seen[names[s]] / 1000.0 - info.graded_at)
    if missing:
        print(f"not shown within 120 s: {', '.join(missing)}")
    if delays:
        ms = [d * 1000 for d in delays]
        print(
            f"score stored -> in the page's leaderboard (DOM), {len(ms)} scores: "
            f"p50 {pct(ms, 0.5):.0f} ms, p99 {pct(ms, 0.99):.0f} ms, max {max(ms):.0f} ms"
        )
    return 0 if delays and not missing else 1


if __name__ == "__main__":
    sys.exit(main())
