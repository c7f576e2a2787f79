"""An agent context's copy of each run's output: numbered as its events number it, bounded."""

from __future__ import annotations

from common.messages import OUTPUT_KEPT_LINES
from services.context.output_tail import OutputTails


def test_lines_are_numbered_across_batches_and_the_last_ones_kept() -> None:
    tails = OutputTails()
    assert tails.add("k1-1-a", "k1", "alice", ["a", "b"]) == 0
    assert tails.add("k1-1-a", "k1", "alice", ["c"]) == 2
    so_far = tails.so_far("k1-1-a")
    assert so_far is not None
    assert (so_far.agent, so_far.user, so_far.first, so_far.lines) == (
        "k1",
        "alice",
        0,
        list("abc"),
    )
    many = [f"line {i}" for i in range(3, 503)]
    assert tails.add("k1-1-a", "k1", "alice", many) == 3
    so_far = tails.so_far("k1-1-a")
    assert so_far is not None
    # 503 printed: the last OUTPUT_KEPT_LINES, and how many came before the first of them
    assert so_far.first == 503 - OUTPUT_KEPT_LINES and so_far.lines == many[-OUTPUT_KEPT_LINES:]
    assert tails.so_far("k1-2-b") is None


def test_the_runs_that_printed_least_lately_are_forgotten_first() -> None:
    tails = OutputTails(runs=3)
    for rid in ("r1", "r2", "r3"):
        tails.add(rid, "k1", "alice", [rid])
    tails.add("r1", "k1", "alice", ["again"])  # r1 printed last: r2 is now the oldest
    tails.add("r4", "k2", "bob", ["r4"])
    assert tails.so_far("r2") is None
    kept = {rid: tails.so_far(rid) for rid in ("r1", "r3", "r4")}
    assert all(k is not None for k in kept.values())
    assert kept["r1"] is not None and kept["r1"].lines == ["r1", "again"]
