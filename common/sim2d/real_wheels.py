"""Wheels that slip and obey late: a real robot's drive, as its twin fitted it.

A robot type's drive may say each wheel makes only ``wheel_scale`` of its commanded
motion (slip, a worn tyre) and obeys a command ``latency_s`` after it was set
(common/sim2d/specs.py DriveSpec; a twin's robot file, common/twin/). The drives'
kernels know neither: around each tick, for those robots only, this part puts in
the world's command array what the wheels do now (the command in force
``latency_s`` ago, scaled), then puts back what was commanded and counts on the
position counters the wheels' own turn, not the slipping robot's motion (a real
robot's encoders count the wheel, so its odometry drifts as the real one's does).

A world whose robots are all the datasheet's never calls it (WorldTicker.step
checks ``Tables.imperfect``, an empty tuple): their trajectories are unchanged
bit for bit.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from common.sim2d.world_state import Tables, WorldState


class RealWheels:
    """The commands waiting out each imperfect robot's latency, and the tick's saved arrays."""

    def __init__(self, state: WorldState) -> None:
        self._state = state
        # (set at sim time, left, right) per slot, oldest first; the first is in force.
        self._orders: dict[int, deque[tuple[float, float, float]]] = {}
        self._tables: Tables | None = None  # the agents the orders are of
        self._commanded = np.zeros((0, 2))
        self._counted = np.zeros((0, 2))

    def before(self, slots: tuple[int, ...]) -> None:
        """Before a tick: each robot's wheels at the command now in force, scaled."""
        s = self._state
        if s.tables is not self._tables:  # agents came or went: the slots changed
            self._orders.clear()
            self._tables = s.tables
        rows = list(slots)
        cmd, now = s.cmd, s.sim_time
        self._commanded = cmd[rows].copy()
        self._counted = s.counters[rows].copy()
        for k, slot in enumerate(slots):
            drive = s.agents[slot].spec.drive
            left, right = float(self._commanded[k, 0]), float(self._commanded[k, 1])
            orders = self._orders.setdefault(slot, deque())
            if not orders or orders[-1][1:] != (left, right):
                orders.append((now, left, right))
            due = now - drive.latency_s + 1e-9  # a command set at ``due`` is obeyed now
            while len(orders) > 1 and orders[1][0] <= due:
                orders.popleft()
            at, left, right = orders[0]
            if at > due:  # the first command is not yet obeyed: the wheels stand
                left = right = 0.0
            cmd[slot, 0] = left * drive.wheel_scale[0]
            cmd[slot, 1] = right * drive.wheel_scale[1]

    def after(self, slots: tuple[int, ...]) -> None:
        """After a tick: the commands as set, the counters as the wheels turned."""
        s = self._state
        cmd, counters = s.cmd, s.counters
        for k, slot in enumerate(slots):
            scale = s.agents[slot].spec.drive.wheel_scale
            for wheel in (0, 1):
                start = self._counted[k, wheel]
                counters[slot, wheel] = start + (counters[slot, wheel] - start) / scale[wheel]
            cmd[slot] = self._commanded[k]
