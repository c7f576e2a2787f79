"""Real robots' states -> wire types: each robot's sample, the arena's frame and sensor batch.

The same types a simulated World packs into (common/world/packing.py), so a
viewer, a recorder or a controller cannot tell a real arena from a simulated one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from common.messages import (
    FINGERS_CLOSED,
    FINGERS_HOLDING,
    FINGERS_OPEN,
    AgentStates,
    GripperReading,
    PackedArray,
    SensorBatch,
    SensorSample,
    WorldFrame,
)
from services.bridge import protocol as P
from services.bridge.robot import GripperState, RobotState

FINGERS_CLOSED_ABOVE = 100  # a finger-position reading above this is a closed grip
FINGER_WORDS = {FINGERS_OPEN: "open", FINGERS_CLOSED: "closed", FINGERS_HOLDING: "holding"}


def byte(value: int) -> int:
    return max(0, min(255, int(value)))


def fingers(g: GripperState) -> int:
    """FINGERS_OPEN, _CLOSED or _HOLDING: closed on something the barrier sees is holding."""
    if g.fingers <= FINGERS_CLOSED_ABOVE:
        return FINGERS_OPEN
    return FINGERS_HOLDING if g.object > 0 else FINGERS_CLOSED


def sample(world: str, agent: str, state: RobotState, t0: float) -> SensorSample | None:
    """The robot's readings as a SensorSample; None until it has been read once whole."""
    if not state.online or None in (state.proximity, state.ambient, state.counters):
        return None
    assert state.proximity is not None and state.ambient is not None
    assert state.counters is not None
    speed = state.speed or P.WheelPair(0, 0)
    gripper = None
    if (g := state.gripper) is not None:
        gripper = GripperReading(
            arm=byte(g.arm),
            fingers=FINGER_WORDS[fingers(g)],  # type: ignore[arg-type]
            presence=byte(g.object),
            resistivity=byte(g.resistivity),
        )
    return SensorSample(
        world=world,
        agent=agent,
        tick=state.rounds,
        sim_time=round(state.updated - t0, 6) if state.updated else 0.0,
        proximity=list(state.proximity),
        ambient=list(state.ambient),
        counters=(state.counters.left, state.counters.right),
        speeds=(speed.left, speed.right),
        leds=list(state.leds),
        gripper=gripper,
    )


def frame(
    world: str, tick: int, sim_time: float, states: Sequence[RobotState], layout: int
) -> WorldFrame:
    """Every robot's pose (the shown one: fused with the camera's) and state, as one frame."""
    n = len(states)
    poses = np.array(
        [(s.pose.x, s.pose.y, s.pose.heading) for s in states], dtype=np.float32
    ).reshape(n, 3)
    agent_states = AgentStates(
        leds=np.array([sum(b << k for k, b in enumerate(s.leds)) for s in states], np.uint8),
        arm=np.zeros(n, np.uint8),
        fingers=np.zeros(n, np.uint8),
        presence=np.zeros(n, np.uint8),
    )
    for i, s in enumerate(states):
        if (g := s.gripper) is not None:
            agent_states.arm[i] = byte(g.arm)
            agent_states.fingers[i] = fingers(g)
            agent_states.presence[i] = byte(g.object)
    return WorldFrame(
        world=world,
        tick=tick,
        sim_time=sim_time,
        layout=layout,
        poses=PackedArray.from_numpy(poses),
        agent_state=agent_states.pack(),
        lights=PackedArray.from_numpy(np.zeros(0, dtype=np.uint8)),
    )


def batch(
    world: str, tick: int, sim_time: float, states: Sequence[RobotState], layout: int
) -> SensorBatch:
    """Every robot's IR, ambient and counters in arrays (an offline robot: dark, nothing)."""
    n = len(states)
    prox = np.zeros((n, 8), dtype=np.uint16)
    amb = np.full((n, 8), 500, dtype=np.uint16)
    counters = np.zeros((n, 2), dtype=np.int32)
    for i, s in enumerate(states):
        if s.proximity is not None:
            prox[i] = s.proximity[:8]
        if s.ambient is not None:
            amb[i] = s.ambient[:8]
        if s.counters is not None:
            counters[i] = (s.counters.left, s.counters.right)
    return SensorBatch(
        world=world,
        tick=tick,
        sim_time=sim_time,
        layout=layout,
        proximity=PackedArray.from_numpy(prox),
        ambient=PackedArray.from_numpy(amb),
        counters=PackedArray.from_numpy(counters),
    )
