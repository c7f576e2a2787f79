"""The example plugin's race rules (examples/plugins/wart-race/wart_race/race.py), pure.

Loaded from its file: the unit tests run without the plugin installed.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

RACE_PY = Path(__file__).resolve().parents[4] / "examples/plugins/wart-race/wart_race/race.py"
spec = importlib.util.spec_from_file_location("wart_race_rules", RACE_PY)
assert spec is not None and spec.loader is not None
rules = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = rules  # dataclasses look their module up
spec.loader.exec_module(rules)

# The left side of the circle below, drawn upwards: a robot going counter-clockwise
# crosses it moving -x, from the line's right to its left.
LINE = (300.0, 300.0, 300.0, 600.0)


def _circle(race, agent: str, laps: float, t0: float = 0.0, cx: float = 450.0) -> float:  # type: ignore[no-untyped-def]
    """Drive ``agent`` counter-clockwise round (cx, 450) at 200 mm radius, from the bottom."""
    steps = int(laps * 72)
    t = t0
    for i in range(steps + 1):
        a = -math.pi / 2 + 2 * math.pi * i / 72
        t = t0 + i * 0.1
        race.update(t, {agent: (cx + 200 * math.cos(a), 450 + 200 * math.sin(a))})
    return t


def test_a_lap_counts_crossing_the_line_leftwards_and_the_first_to_finish_wins() -> None:
    race = rules.Race(LINE, laps=2)
    _circle(race, "a", 2.5)
    _circle(race, "b", 1.5)
    assert race.laps_done == {"a": 2, "b": 1}
    assert race.finished and race.winner == "a"
    standings = race.standings()
    assert [s["agent"] for s in standings] == ["a", "b"]
    assert standings[1]["finished_at"] is None


def test_backwards_and_beside_the_line_do_not_count() -> None:
    race = rules.Race(LINE, laps=5)
    for x in (290.0, 310.0, 290.0, 310.0):  # rightwards across x=300: backwards, twice
        race.update(0.0, {"r": (x, 450.0)})
    assert race.laps_done["r"] == 1  # only the one leftward crossing (310 -> 290) between
    for x in (310.0, 290.0):  # beside the segment (y=100, below its end)
        race.update(0.0, {"s": (x, 100.0)})
    assert race.laps_done["s"] == 0
