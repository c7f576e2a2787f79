"""A heat of several entries in one world (services/runner/heat.py), on this machine's
sandbox: one entry's loop ends only its own run, and entries that meet both count it."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from common.messages import Heat, HeatEntry
from services.runner.heat import run_heat
from tests.conftest import REPO, needs_sandbox

pytestmark = needs_sandbox
GRADING = Path(__file__).parent / "grading"


def test_a_looping_entry_ends_alone_and_the_others_run_their_time() -> None:
    duel = json.loads((REPO / "maps" / "empty.json").read_text())
    duel["agents"] += [
        {"id": "k2", "type": "khepera", "x": 800, "y": 200},
        {"id": "k3", "type": "khepera", "x": 800, "y": 800},
    ]

    def entry(agent: str, name: str, x: float, heading: float) -> HeatEntry:
        return HeatEntry(submission=f"s-{agent}", user="u", agent=agent, x=x, y=500,
                         heading=heading, source=(GRADING / f"{name}.py").read_bytes(),
                         filename=f"{name}.py")  # fmt: skip

    request = Heat(
        competition="c", heat=1, map=json.dumps(duel), seed=1, seconds=3.0,
        entries=[entry("k1", "works", 300, 0.0), entry("k2", "works", 600, math.pi),
                 entry("k3", "loops", 150, 0.0)],
    )  # fmt: skip
    works, other, looped = run_heat(request).entries
    assert looped.cause == "timeout" and looped.steps < works.steps, looped
    for r in (works, other):  # the loop held them for one tick's limit, not the heat's
        assert r.cause == "ok" and r.sim_seconds == pytest.approx(3.0), r
        assert r.collisions.get("robot") == 1  # k1 and k2 met: one robot collision each
