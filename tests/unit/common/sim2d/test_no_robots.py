"""A world on the discs drive with no robots (its last one deleted) steps on the fused,
ahead-of-time path: the general path's numba kernel would be loaded or compiled at that
first tick, seconds in which an engine answers no snapshot and no edit."""

from __future__ import annotations

import time

import numpy as np

from common.sim2d import maps
from tests.conftest import REPO


def test_deleting_the_last_robot_keeps_the_world_on_the_fused_path() -> None:
    world = maps.load_map(REPO / "maps" / "foraging.json", name="w1", seed=3)
    assert world.drive == "discs"
    for _ in range(50):  # the robots drive into the balls: some move
        world.cmd[:] = (60, 60)
        world.step()
    world.remove("ball0")
    for ident in ("k3", "k2", "k1", "k0"):
        world.remove(ident)
        world.step()
    balls = np.array(world.object_pose, copy=True)
    started = time.perf_counter()
    for _ in range(25):
        world.step()
    assert world.ticker.fused is not None  # the fused path, not numba's general one
    assert time.perf_counter() - started < 1.0
    assert np.array_equal(world.object_pose, balls)  # nothing pushes them any more
    assert world.tick == 50 + 4 + 25  # every step counted
