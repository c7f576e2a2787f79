"""The world frame a viewer draws (common/world/packing.py): each robot's LEDs, arm, grip.

What a user relies on: the frame's agent_state row of a robot says which of
its LEDs are lit (bit i for LED i), where its arm is, whether its fingers are
open, closed or holding something, and what its barrier sees.
"""

from __future__ import annotations

import numpy as np

from common.messages import (
    FINGERS_CLOSED,
    FINGERS_HOLDING,
    FINGERS_OPEN,
    AgentStates,
    PackedArray,
)
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
    assert frame.agent_state.to_numpy().dtype == np.uint8
    states = AgentStates.unpack(frame.agent_state, 3)
    assert states is not None
    assert states.leds.tolist() == [0b11, 0, 0b10]
    assert states.arm.tolist() == np.clip(world.arm, 0, 255).astype(np.uint8).tolist()
    assert states.fingers.tolist() == [FINGERS_OPEN, FINGERS_CLOSED, FINGERS_HOLDING]
    assert states.presence.tolist() == np.clip(world.presence, 0, 255).tolist()
    assert frame.poses.to_numpy().shape == (3, 3)


def test_agent_states_round_trip_and_a_frame_of_another_shape_is_refused() -> None:
    states = AgentStates(
        leds=np.array([1, 2], np.uint8),
        arm=np.array([165, 255], np.uint8),
        fingers=np.array([FINGERS_OPEN, FINGERS_HOLDING], np.uint8),
        presence=np.array([0, 255], np.uint8),
    )
    packed = states.pack()
    back = AgentStates.unpack(packed, 2)
    assert back is not None
    for column in ("leds", "arm", "fingers", "presence"):
        assert getattr(back, column).tolist() == getattr(states, column).tolist()
    assert AgentStates.unpack(packed, 3) is None  # a frame of another layout: refetch
    assert AgentStates.unpack(PackedArray.from_numpy(np.zeros(8, np.uint8)), 2) is None
