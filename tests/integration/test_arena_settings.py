"""``wart arena settings`` sets what the page's arena panel sets, with real processes:
the slot length, and remote control on or off for the arena or one robot (issue 38)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import Procs, Router
from tests.kit.agentkit import CTX, agent_user, start_agent_context, start_engine
from tests.kit.lab import PASSWORD, ProcessLab, make_lab


@pytest.fixture
def lab(router: Router, procs: Procs, tmp_path: Path) -> Iterator[ProcessLab]:
    lab = make_lab(router, procs, tmp_path)
    lab.start_registry()
    start_engine(lab)
    start_agent_context(lab, slot=30.0)
    yield lab


def test_wart_arena_settings_shows_and_sets_the_slot_and_remote_control(
    lab: ProcessLab, procs: Procs
) -> None:
    runs = 0

    def arena(user: str, *extra: str) -> tuple[int, str]:
        nonlocal runs
        runs += 1
        args = ["arena", *lab.net_args(), "settings", "--context", CTX, "--user", user, *extra]
        proc = procs.start(f"arena-settings-{runs}", args, env={"WART_PASSWORD": PASSWORD})
        return proc.popen.wait(60), proc.output()

    code, out = arena("ida")  # no change: what the page's panel shows
    assert code == 0 and "slot length   30 s" in out and "robots off    none" in out, out
    code, out = arena("bob", "--slot", "45")  # a student may not
    assert code == 1 and "only the owner of arena or a user with 'kick'" in out, out
    code, out = arena("ida", "--slot", "45", "--disable", "--agent", "k1")
    assert code == 0, out
    assert "slot length   45 s" in out and "robots off    k1" in out, out
    with agent_user(lab, "carol") as carol:
        state = carol.state()
        assert state.slot_seconds == 45.0
        assert {q.agent: q.enabled for q in state.agents}["k1"] is False
        assert state.enabled is True
    code, out = arena("ida", "--enable", "--agent", "k1")
    assert code == 0 and "robots off    none" in out, out
    # Refused before anything is sent, in words.
    code, out = arena("ida", "--slot", "0.5")
    assert code == 1 and "--slot must be between 1 and 3600 seconds, not 0.5" in out, out
    code, out = arena("ida", "--agent", "k1")
    assert code == 1 and "--agent says which robot --enable or --disable" in out, out
    code, out = arena("ida", "--enable", "--disable")
    assert code == 2 and "not allowed with argument" in out, out
    code, out = arena("ida", "--help")
    assert code == 0 and "--slot SLOT" in out and "--disable" in out, out
