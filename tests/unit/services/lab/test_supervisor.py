"""The supervisor starts a wave of services together and says which came up."""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from services.lab import supervisor as supervisor_module
from services.lab.supervisor import ChildSpec, Supervisor
from tests.kit.waits import wait_for


class Watch:
    """Stands in for the liveliness watch: a key is "up" once every key was asked for.

    A supervisor that waits for one child before it starts the next never
    gets there (each wait would time out), so "up" proves the waits overlap.
    """

    def __init__(self, expected: set[str], never: set[str] = frozenset()) -> None:
        self.expected = expected
        self.never = never
        self.asked: set[str] = set()
        self.cond = threading.Condition()

    def wait(self, key: str, timeout: float, abort: Callable[[], bool] = lambda: False) -> bool:
        with self.cond:
            self.asked.add(key)
            self.cond.notify_all()
            if key not in self.expected:  # a child that never says it is alive
                deadline = time.monotonic() + timeout
                while not abort() and time.monotonic() < deadline:
                    self.cond.wait(0.05)
                return False
            everyone = self.cond.wait_for(lambda: self.asked >= self.expected, timeout)
        return everyone and key not in self.never

    def close(self) -> None:
        pass


@pytest.fixture
def sleeper(monkeypatch: pytest.MonkeyPatch) -> None:
    """Children that just live (a real process each, without the lab's imports)."""

    def command(args: Sequence[str]) -> list[str]:
        if args and args[0] == "exit":
            return [sys.executable, "-c", "raise SystemExit(3)"]
        return [sys.executable, "-c", "import time; time.sleep(60)"]

    monkeypatch.setattr(supervisor_module, "wart_command", command)


def spec(name: str, *, timeout: float = 5.0, argv: Sequence[str] = ("live",)) -> ChildSpec:
    return ChildSpec(name=name, argv=list(argv), alive_key=f"alive/{name}", ready_timeout=timeout)


def test_a_wave_starts_together_and_reports_each_child_in_order(
    tmp_path: Path, sleeper: None
) -> None:
    said: list[str] = []
    sup = Supervisor(tmp_path / "logs", say=said.append)
    names = ["chat", "engine", "runner", "viewer"]
    sup.watch = Watch({f"alive/{n}" for n in names})  # type: ignore[assignment]
    try:
        results = sup.start_together([spec(n) for n in names])
    finally:
        sup.stop_all(timeout=2.0)
    assert [(child.spec.name, up) for child, up in results] == [(n, True) for n in names]
    assert sorted(line.split()[1] for line in said) == sorted(names)
    assert all(" up " in line for line in said), said


def test_a_child_that_does_not_come_up_is_named_and_the_others_still_start(
    tmp_path: Path, sleeper: None
) -> None:
    said: list[str] = []
    sup = Supervisor(tmp_path / "logs", say=said.append)
    sup.watch = Watch({"alive/chat", "alive/engine"}, never={"alive/engine"})  # type: ignore[assignment]
    try:
        results = sup.start_together(
            [spec("chat"), spec("engine", timeout=1.0), spec("bridge", argv=["exit"])]
        )
    finally:
        sup.stop_all(timeout=2.0)
    assert [up for _, up in results] == [True, False, False]
    failed = [line for line in said if "did not come up" in line]
    assert any("bridge" in line and "exit" in line for line in failed), said
    # The engine is alive, only slow: said to be still starting, never to have failed.
    assert not any("engine" in line for line in failed), said
    assert any("engine" in line and "still starting" in line for line in said), said


class SlowWatch:
    """``slow`` comes up only after ``delay`` seconds; the others at once."""

    def __init__(self, slow: str, delay: float) -> None:
        self.slow, self.up_at = slow, time.monotonic() + delay

    def wait(self, key: str, timeout: float, abort: Callable[[], bool] = lambda: False) -> bool:
        if key != self.slow:
            return True
        wait = self.up_at - time.monotonic()
        if wait > timeout:
            time.sleep(timeout)
            return False
        time.sleep(max(0.0, wait))
        return True

    def close(self) -> None:
        pass


def test_the_viewer_is_announced_while_a_slow_engine_still_starts(
    tmp_path: Path, sleeper: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a checkout's first start the engine compiles for a while: the web address is said
    as soon as the viewer is up, and the engine is said to be still starting."""
    monkeypatch.setattr(supervisor_module, "STILL_STARTING_S", 0.3)
    said: list[str] = []
    sup = Supervisor(tmp_path / "logs", say=said.append)
    sup.watch = SlowWatch("alive/engine", delay=1.5)  # type: ignore[assignment]
    announced: list[tuple[str, int]] = []
    try:
        results = sup.start_together(
            [spec("engine"), spec("viewer")],
            on_up=lambda child: announced.append((child.spec.name, len(said))),
        )
    finally:
        sup.stop_all(timeout=2.0)
    assert [up for _, up in results] == [True, True]
    assert [name for name, _ in announced] == ["viewer", "engine"]  # the viewer first
    starting = [i for i, line in enumerate(said) if "still starting" in line]
    assert len(starting) == 1 and "engine" in said[starting[0]], said
    assert announced[0][1] <= starting[0]  # said before the engine was even called slow


def test_a_child_slower_than_its_ready_time_is_said_up_when_it_comes_up(
    tmp_path: Path, sleeper: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A busy machine's first start: the engine's kernels took minutes. It is said to be
    starting, with how long so far, then up, never that it failed."""
    monkeypatch.setattr(supervisor_module, "STILL_STARTING_S", 0.2)
    monkeypatch.setattr(supervisor_module, "STARTING_EVERY_S", 0.3)
    said: list[str] = []
    sup = Supervisor(tmp_path / "logs", say=said.append)
    sup.watch = SlowWatch("alive/engine", delay=2.0)  # type: ignore[assignment]
    try:
        results = sup.start_together([spec("engine", timeout=0.8)])
        assert [up for _, up in results] == [False]  # not up in its time: the lab goes on
        wait_for(lambda: any("✓" in line for line in said), 10, what="the late engine's up")
    finally:
        sup.stop_all(timeout=2.0)
    assert not any("did not come up" in line for line in said), said
    assert any(re.search(r"still starting \(\d+ s so far\)", line) for line in said), said
    assert any("not up after" in line and "said here when it is up" in line for line in said)
    up = next(line for line in said if "✓" in line)
    assert re.search(r"after \d+ s\)", up), up
