"""The supervisor starts a wave of services together and says which came up."""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from services.lab import supervisor as supervisor_module
from services.lab.supervisor import ChildSpec, Supervisor


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
    assert any("engine" in line for line in failed), said
    assert any("bridge" in line and "exit" in line for line in failed), said
