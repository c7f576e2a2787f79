"""The discs drive's fused tick (common/sim2d/fused.py): one compiled call, the same run.

What a user relies on: a world on the discs drive gives the same poses,
velocities, counters and readings, bit for bit, whether a tick runs as one
compiled call or as the general path (a profiled world takes the latter);
edits between ticks (a move, new counters, a robot added or removed, an
obstacle) are seen by the next tick; a swarm sensed on two threads (outside
the fused call) runs the one-thread run; and arrays a caller took from the world
do not change under it when the world steps on.
"""

from __future__ import annotations

import numpy as np
import pytest

from common.sim2d import packs, sensing
from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.world import EditError, World
from tests.kit.worlds import advance, build, control

KHEPERA = agent_type("khepera")


def _state(world: World) -> list[np.ndarray]:
    return [
        world.agent_pose.copy(),
        world.agent_vel.copy(),
        world.counters.copy(),
        world.proximity.copy(),
        world.ambient.copy(),
        world.presence.copy(),
    ]


def _add_block(world: World) -> None:
    """A box where no robot is: the first free spot of a row (both worlds find the same)."""
    for x in np.arange(100.0, world.width - 100.0, 50.0):
        try:
            world.add_obstacle("block", ShapeSpec.box(40, 40), float(x), world.height / 2)
        except EditError:
            continue
        return
    raise AssertionError("no free spot for the block")


def _run_both(script: list[tuple[int, str]], ticks: int) -> None:
    """The same world and edits, fused and general (profile=True): equal at every tick."""
    fast = build(40, drive="discs", sensor_period_s=0.01)
    slow = build(40, drive="discs", sensor_period_s=0.01)
    slow.profile = True
    edits = dict(script)
    for t in range(ticks):
        for world in (fast, slow):
            edit = edits.get(t)
            if edit == "move":
                world.move("k3", 300.0, 310.0, 1.0)
            elif edit == "counters":
                world.set_counters(5, 1000, -1000)
            elif edit == "add":
                world.add_agent("extra", KHEPERA, 100.0, 100.0, 0.5)
            elif edit == "remove":
                world.remove("k7")
            elif edit == "obstacle":
                _add_block(world)
            elif edit == "light":
                world.add_light("lamp2", 300.0, 300.0, radius_mm=400.0)
            control(world)
            world.step()
        for a, b in zip(_state(fast), _state(slow), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"tick {t}")
    assert fast.ticker.fused is not None, "the fused path ran"


def test_the_fused_tick_runs_the_general_paths_run_bit_for_bit() -> None:
    _run_both([], 60)


def test_edits_between_ticks_are_seen_by_the_next_fused_tick() -> None:
    script = [(5, "move"), (9, "counters"), (14, "add"), (20, "remove"), (26, "obstacle")]
    _run_both([*script, (31, "light")], 45)


def test_arrays_taken_from_the_world_keep_their_values() -> None:
    world = advance(build(10, drive="discs", sensor_period_s=0.01), 3)
    held = [world.agent_pose, world.agent_vel, world.proximity, world.ambient, world.presence]
    copies = [a.copy() for a in held]
    advance(world, 20)
    for a, b in zip(held, copies, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(world.agent_pose, copies[0]), "the robots did move"


@pytest.mark.skipif(packs.MAX_THREADS < 2, reason="numba has one thread here")
def test_a_swarm_on_two_threads_runs_the_one_thread_run_bit_for_bit() -> None:
    # Past sensing.PARALLEL_MIN_AGENTS a world with two threads runs its drive
    # in the fused call and its sensing pass on numba's threads, in the fused
    # state's arrays; one thread runs both in the fused call; a profiled world
    # runs the general path. All three: the same run.
    n = 2 * sensing.PARALLEL_MIN_AGENTS
    one = build(n, seed=5, drive="discs")
    two = build(n, seed=5, drive="discs", threads=2)
    general = build(n, seed=5, drive="discs", threads=2)
    general.profile = True
    for t in range(25):
        for world in (one, two, general):
            control(world)
            world.step()
        for a, b, c in zip(_state(one), _state(two), _state(general), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"tick {t}")
            np.testing.assert_array_equal(a, c, err_msg=f"tick {t}")
    assert one.ticker.fused is not None and two.ticker.fused is not None


def test_a_world_switching_between_fused_and_general_ticks_runs_the_general_run() -> None:
    # A profiled tick takes the general path: the fused state built before it
    # must not carry on from where it was.
    switching = build(30, drive="discs", sensor_period_s=0.01)
    general = build(30, drive="discs", sensor_period_s=0.01)
    general.profile = True
    for t in range(40):
        switching.profile = 10 <= t < 15 or t == 30
        for world in (switching, general):
            control(world)
            world.step()
        for a, b in zip(_state(switching), _state(general), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"tick {t}")
