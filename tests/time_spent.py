"""Where the suite's time went: each xdist group's and each worker's busy seconds.

Printed at the end of every run (a pytest plugin, registered in tests/conftest.py):
the run's wall time is at least its busiest worker's, and a group runs on one
worker, so the top lines say what to split or speed up first.
"""

from __future__ import annotations

import json
import os
from collections import defaultdict

import pytest

SHOWN = 12  # the busiest groups listed
# Set to a file name to get every test phase's seconds as JSON lines (for profiling the suite).
DUMP_ENV = "WART_TIME_SPENT_FILE"


class TimeSpent:
    def __init__(self) -> None:
        self.by_worker: dict[str, float] = defaultdict(float)
        self.by_group: dict[str, float] = defaultdict(float)
        self.tests_in_group: dict[str, set[str]] = defaultdict(set)
        self.dump_path = os.environ.get(DUMP_ENV) or None

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        node = getattr(report, "node", None)  # the worker that ran it, under xdist
        worker = node.gateway.id if node is not None else "main"
        nodeid, _, group = report.nodeid.partition("@")
        group = group or "(no group)"
        self.by_worker[worker] += report.duration
        self.by_group[group] += report.duration
        self.tests_in_group[group].add(nodeid)
        if self.dump_path is not None:
            line = {"test": nodeid, "group": group, "worker": worker}
            line |= {"phase": report.when, "seconds": round(report.duration, 3)}
            with open(self.dump_path, "a") as out:
                out.write(json.dumps(line) + "\n")

    def pytest_terminal_summary(self, terminalreporter: pytest.TerminalReporter) -> None:
        if not self.by_worker:
            return
        write = terminalreporter.write_line
        terminalreporter.section("where the time went (busy seconds)")
        workers = sorted(self.by_worker.items(), key=lambda kv: -kv[1])
        write("workers: " + ", ".join(f"{w} {s:.0f} s" for w, s in workers))
        groups = sorted(self.by_group.items(), key=lambda kv: -kv[1])
        for group, seconds in groups[:SHOWN]:
            write(f"{seconds:7.0f} s  {group} ({len(self.tests_in_group[group])} tests)")
