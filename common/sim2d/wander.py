"""A built-in obstacle-avoidance rule for robots that no controller drives.

``wart engine --wander`` runs it every tick on each robot without a recent
command, so an arena is alive with nobody logged in (an open day, a swarm on a
wall screen, a viewer benchmark that needs moving robots). A robot whose lease
holder sends commands is left to its controller; when the commands stop, the
watchdog halts it and the rule takes it over again on the next tick.

The rule is a Braitenberg vehicle on the Khepera's eight IR sensors: what a
side sensor sees speeds up the wheel on that side and slows the other, so the
robot turns away from it (the front pair turns it too, away from the nearer
side). Robots with another sensor layout keep their command.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

# Sensor order (common/sim2d/agents/khepera.py): 0 left, 1 front-left, 2-3 front, 4 front-right,
# 5 right, 6-7 back. The back sensors do not steer.
_W_LEFT = np.array([4, 3, 2, 1, -1, -2, 0, 0]) / 400.0
_W_RIGHT = _W_LEFT[[5, 4, 3, 2, 1, 0, 6, 7]]  # the mirror image: sensor i <-> sensor 5 - i
WEIGHTS = np.stack([_W_LEFT, _W_RIGHT], axis=1)  # (8, 2): both wheels in one product
CRUISE = 8.0  # pulses per 10 ms: 64 mm/s, a calm walking pace for a Khepera


def braitenberg(proximity: npt.NDArray[np.floating], cruise: float = CRUISE) -> npt.NDArray:
    """(N, 2) wheel speeds from (N, >= 8) proximity readings (0..1023)."""
    return cruise + proximity[:, : len(WEIGHTS)] @ WEIGHTS
