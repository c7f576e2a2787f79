"""The world frame a viewer draws (common/world/packing.py): each robot's LEDs, arm, grip.

What a user relies on: the frame's agent_state row of a robot says which of
its LEDs are lit (bit i for LED i), where its arm is, whether its fingers are
open, closed or holding something, and what its barrier sees.
"""

from __future__ import annotations

import numpy as np

from common.sim2d.agents import agent_type
from common.sim2d.world import World
from common.world import packing


def test_a_frame_carries_each_robots_leds_arm_and_grip() -> None:
    world = World(600.0, 600.0, seed=1)
    for i in range(3):
        world.add_agent(f"k{i}", agent_type("khepera"), 100.0 + 150 * i, 300.0, 0.0, gripper=True)
    world.set_leds(0, [True, True])  # a Khepera has two LEDs
    world.set_leds(2, [False, True])
    world.set_grip(1, True)
    world.step()
    world.holding = lambda: np.array([False, False, True])  # type: ignore[method-assign]
    frame = packing.frame(world)
    state = frame.agent_state.to_numpy()
    assert state.shape == (3, 4) and state.dtype == np.uint8
    assert state[:, 0].tolist() == [0b11, 0, 0b10]
    assert state[:, 1].tolist() == np.clip(world.arm, 0, 255).astype(np.uint8).tolist()
    assert state[:, 2].tolist() == [0, 1, 2]  # open, closed, holding
    assert frame.poses.to_numpy().shape == (3, 3)
