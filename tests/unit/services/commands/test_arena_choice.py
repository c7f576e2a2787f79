"""Arena placement: by name, or the least busy host that accepts."""

from __future__ import annotations

import pytest

from common.messages.host import ArenaInfo, HostLoad
from services.commands.arena import ArenaError, choose_host


def load(host: str, arenas: int, cpu: float, accepting: bool = True, reason: str = "") -> HostLoad:
    infos = [
        ArenaInfo(
            world=f"{host}w{i}",
            host=host,
            map="m",
            robots=1,
            owner="x",
            state="running",
            started_at=0.0,
        )
        for i in range(arenas)
    ]
    return HostLoad(
        host=host,
        at=0.0,
        cpus=2,
        cpu_percent=cpu,
        load1=0.0,
        mem_total_mb=1000,
        mem_available_mb=500,
        services=[],
        arenas=infos,
        max_arenas=4,
        accepting=accepting,
        reason=reason,
    )


def test_least_busy_accepting_host_wins() -> None:
    loads = [
        load("A", 0, 5, accepting=False, reason="no arenas"),
        load("B", 2, 10),
        load("C", 1, 90),
    ]
    assert choose_host(loads).host == "C"  # fewer arenas first, then CPU
    assert choose_host([load("B", 1, 50), load("C", 1, 20)]).host == "C"


def test_named_host_and_clear_refusals() -> None:
    loads = [load("A", 0, 5, accepting=False, reason="no arenas"), load("B", 0, 10)]
    assert choose_host(loads, "B").host == "B"
    with pytest.raises(ArenaError, match="host A takes no arena now: no arenas"):
        choose_host(loads, "A")
    with pytest.raises(ArenaError, match="host Z did not answer"):
        choose_host(loads, "Z")
    with pytest.raises(ArenaError, match="no host serves this lab"):
        choose_host([])
    with pytest.raises(ArenaError, match="A: no arenas"):
        choose_host(loads[:1])
