"""The discs drive on two threads (common/sim2d/discs_split.py): the serial run, bit for bit.

What a user relies on: a swarm world given threads runs exactly the run it
would on one thread: the same poses, velocities, counters, balls and
readings at every tick, whether the drive runs in the fused call or on the
threads, and on the general path (a profiled world) too. The split starts at
discs_split.SPLIT_MIN_DISCS discs; here it is forced on small worlds (two
threads), so that the tests stay quick.
"""

from __future__ import annotations

import numpy as np
import pytest

from common.sim2d import discs_split, packs, sensing
from common.sim2d.entities import ShapeSpec
from tests.kit.worlds import build, control, tick_digest

pytestmark = [
    pytest.mark.skipif(packs.MAX_THREADS < 2, reason="numba has one thread here"),
    # The hang guard times each test alone, not _compiled (numba's first compile of the
    # split drive took over 120 s on a fresh cache beside a CI run).
    pytest.mark.timeout(func_only=True),
]


@pytest.fixture(scope="module", autouse=True)
def _compiled() -> None:
    """numba compiles the split drive and the sensing on threads at their first tick: a
    minute or more of a core on a fresh cache (jitcache.py), longer on a busy machine.
    One tick of each kind of world here compiles what the tests run, or loads it."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(discs_split, "SPLIT_MIN_DISCS", 1)
        patch.setattr(sensing, "PARALLEL_MIN_AGENTS", 1)
        for balls in (0.5, 0.0):
            for threads, profile in ((1, False), (2, False), (2, True)):
                world = build(4, seed=3, drive="discs", balls=balls, threads=threads)
                world.profile = profile
                control(world)
                world.step()


@pytest.fixture(autouse=True)
def _split_from_the_first_disc(monkeypatch: pytest.MonkeyPatch) -> None:
    # Every test here: split from the first disc, sensing on threads from the
    # first robot: the swarm's paths on a small world.
    monkeypatch.setattr(discs_split, "SPLIT_MIN_DISCS", 1)
    monkeypatch.setattr(sensing, "PARALLEL_MIN_AGENTS", 1)


def _runs(n: int, ticks: int, balls: float) -> None:
    serial = build(n, seed=3, drive="discs", balls=balls)
    split = build(n, seed=3, drive="discs", balls=balls, threads=2)
    general = build(n, seed=3, drive="discs", balls=balls, threads=2)
    general.profile = True  # the general path: discs_split.tick
    worlds = (serial, split, general)
    for t in range(ticks):
        digests = []
        for world in worlds:
            control(world)
            world.step()
            digests.append(tick_digest(world))
        assert digests[1] == digests[0], f"fused, split: tick {t}"
        assert digests[2] == digests[0], f"general, split: tick {t}"
    assert split.ticker.fused is not None and split.ticker.fused.split is not None, (
        "the split drive ran"
    )
    assert serial.ticker.fused is not None and serial.ticker.fused.split is None
    assert not np.array_equal(serial.agent_pose, build(n, seed=3).agent_pose), "robots moved"


@pytest.mark.parametrize(("n", "balls"), [(10, 0.5), (300, 0.0), (300, 0.5)])
def test_the_split_drive_runs_the_serial_run_bit_for_bit(n: int, balls: float) -> None:
    _runs(n, 40, balls)


def test_a_crowd_past_the_threads_pair_lists_runs_the_serial_run(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Lists of no pair a chunk: every tick with a pair overflows them and falls
    # back to the serial scan (the same pairs).
    monkeypatch.setattr(discs_split, "PAIRS_PER_DISC", 0)
    assert discs_split.split_buffers(450)[2].shape[1] == 0
    _runs(300, 20, 0.5)


def test_a_crowd_driven_into_a_corner_runs_the_serial_run() -> None:
    # Robots flat out into a corner, pressed together against the walls: the
    # layers and the sweeps (serial in both) get the split's pairs and pushes
    # in the serial order.
    worlds = [build(40, seed=4, drive="discs", balls=0.5, threads=t) for t in (1, 2)]
    for world in worlds:
        for i, (x, y, _) in enumerate(world.agent_pose.copy()):
            world.move(f"k{i}", float(x), float(y), float(np.arctan2(-y, -x)))
    for t in range(100):
        digests = []
        for world in worlds:
            world.set_speeds_all(np.full((len(world.agents), 2), 127.0))
            world.step()
            digests.append(tick_digest(world))
        assert digests[1] == digests[0], f"tick {t}"
    pose = worlds[0].agent_pose
    gaps = np.hypot(*(pose[:, None, :2] - pose[None, :, :2]).transpose(2, 0, 1))
    assert (gaps[np.triu_indices(len(pose), 1)] < 56.0).sum() > 30, "a crowd formed"


def test_edits_between_split_ticks_are_seen_as_by_the_serial_drive() -> None:
    # A move, new counters, a robot added and one removed, an obstacle: the
    # split drive's arrays are rebuilt with the fused state's.
    worlds = [build(30, seed=6, drive="discs", balls=0.5, threads=t) for t in (1, 2)]
    khepera = worlds[0].agents[0].spec
    for t in range(40):
        digests = []
        for world in worlds:
            if t == 5:
                world.move("k3", 300.0, 310.0, 1.0)
            elif t == 9:
                world.set_counters(5, 1000, -1000)
            elif t == 14:
                world.add_agent("extra", khepera, 100.0, 100.0, 0.5)
            elif t == 20:
                world.remove("k7")
            elif t == 26:
                world.add_obstacle("block", ShapeSpec.box(40, 40), 560.0, 40.0)
            control(world)
            world.step()
            digests.append(tick_digest(world))
        assert digests[1] == digests[0], f"tick {t}"
    assert worlds[1].ticker.fused is not None and worlds[1].ticker.fused.split is not None
