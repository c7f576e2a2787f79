"""Where the suite's time went: each xdist group's and each worker's busy seconds, and
the CPU each spent.

Printed at the end of every run (two pytest plugins, registered in tests/conftest.py):
the run's wall time is at least its busiest worker's, and a group runs on one
worker, so the top lines say what to split or speed up first. On a machine with
fewer cores than workers the CPU is what runs out: a test's CPU is its worker's
own (every thread: the test, its in-process services, its Zenoh sessions) and
that of the processes it started and reaped (services, Chromium, CLI calls).
"""

from __future__ import annotations

import json
import os
import resource
import time
from collections import defaultdict
from collections.abc import Iterator

import pytest

from tests.kit.forkserver import forked_cpu

SHOWN = 12  # the busiest groups listed
# Set to a file name to get every test phase's seconds as JSON lines (for profiling the suite).
DUMP_ENV = "WART_TIME_SPENT_FILE"


def _children_cpu() -> float:
    """Of the processes ended so far: those this process started, and those the kit's fork
    server forked for it."""
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime + forked_cpu()


class PhaseCpu:
    """Where a test runs (a worker, or the only process): each phase's CPU, sent with its
    report (user_properties travel from xdist's workers to the controller)."""

    def __init__(self) -> None:
        self._spent: dict[str, tuple[float, float]] = {}

    def _measure(self, item: pytest.Item, when: str) -> Iterator[None]:
        own, children = time.process_time(), _children_cpu()
        yield
        self._spent[f"{item.nodeid}|{when}"] = (
            time.process_time() - own,
            _children_cpu() - children,
        )

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_setup(self, item: pytest.Item) -> Iterator[None]:
        yield from self._measure(item, "setup")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item: pytest.Item) -> Iterator[None]:
        yield from self._measure(item, "call")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_teardown(self, item: pytest.Item) -> Iterator[None]:
        yield from self._measure(item, "teardown")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_makereport(
        self, item: pytest.Item, call: pytest.CallInfo[None]
    ) -> Iterator[None]:
        outcome = yield
        spent = self._spent.pop(f"{item.nodeid}|{call.when}", None)
        if spent is not None:
            report = outcome.get_result()
            report.user_properties.append(("cpu_s", round(spent[0] + spent[1], 3)))
            # The worker's own share apart: a child's CPU counts when it is reaped,
            # which may be in a later test than the one that started it.
            report.user_properties.append(("own_cpu_s", round(spent[0], 3)))


class TimeSpent:
    def __init__(self) -> None:
        self.by_worker: dict[str, float] = defaultdict(float)
        self.by_group: dict[str, float] = defaultdict(float)
        self.cpu_by_group: dict[str, float] = defaultdict(float)
        self.tests_in_group: dict[str, set[str]] = defaultdict(set)
        self.dump_path = os.environ.get(DUMP_ENV) or None

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        node = getattr(report, "node", None)  # the worker that ran it, under xdist
        worker = node.gateway.id if node is not None else "main"
        nodeid, _, group = report.nodeid.partition("@")
        group = group or "(no group)"
        self.by_worker[worker] += report.duration
        self.by_group[group] += report.duration
        properties = dict(report.user_properties)
        cpu = properties.get("cpu_s", 0.0)
        self.cpu_by_group[group] += float(cpu)  # type: ignore[arg-type]
        self.tests_in_group[group].add(nodeid)
        if self.dump_path is not None:
            line = {"test": nodeid, "group": group, "worker": worker}
            line |= {"phase": report.when, "seconds": round(report.duration, 3), "cpu_s": cpu}
            line["own_cpu_s"] = properties.get("own_cpu_s", 0.0)
            with open(self.dump_path, "a") as out:
                out.write(json.dumps(line) + "\n")

    def pytest_terminal_summary(self, terminalreporter: pytest.TerminalReporter) -> None:
        if not self.by_worker:
            return
        write = terminalreporter.write_line
        terminalreporter.section("where the time went (busy seconds, CPU seconds)")
        workers = sorted(self.by_worker.items(), key=lambda kv: -kv[1])
        write("workers: " + ", ".join(f"{w} {s:.0f} s" for w, s in workers))
        write(f"CPU of the tests and what they started: {sum(self.cpu_by_group.values()):.0f} s")
        groups = sorted(self.by_group.items(), key=lambda kv: -kv[1])
        for group, seconds in groups[:SHOWN]:
            cpu = self.cpu_by_group[group]
            tests = len(self.tests_in_group[group])
            write(f"{seconds:7.0f} s {cpu:6.0f} s CPU  {group} ({tests} tests)")
