"""The discs drive's object arrays, built in plain numpy (common/sim2d/pucks.py moves them).

Apart from pucks.py's kernels so the world (world_discs.py, world_tick.py)
builds them without importing numba: an engine on the ahead-of-time kernels
(common/sim2d/aot.py) never loads numba's runtime. pucks.py re-exports them.
"""

from __future__ import annotations

import numpy as np

FLOOR_G_MM_S2 = 9810.0  # bodies.GRAVITY_MM_S2: the floor friction's normal force per gram


def objects_table(k: int, n: int) -> tuple[np.ndarray, ...]:
    """Empty per-object arrays for ``k`` objects and ``n`` robots (world_discs builds real ones)."""
    return (
        np.zeros((k, 3)),  # pose: x, y, heading (moved in place)
        np.zeros((k, 3)),  # vel: vx, vy (mm/s), turn rate (moved in place)
        np.zeros(k),  # decel: mu * g (mm/s^2)
        np.full(k, -1, dtype=np.int64),  # holder: the robot's slot, -1 on the floor
        np.zeros((k, 3)),  # offset: a held object's x, y, heading in its holder's frame
        np.zeros((n, 4)),  # grip: x0, x1, half gap, lowered_above (inf: no gripper)
        np.zeros(n, dtype=np.int8),  # fingers: World.fingers itself (0 open)
        np.zeros(k, dtype=np.bool_),  # round: a circle (else a box or polygon: edges)
        np.zeros((0, 2)),  # local vertices of the edged objects, one run each
        np.zeros(k + 1, dtype=np.int64),  # vertex runs: object j's are [vstart[j], vstart[j+1])
        np.zeros(k),  # radius: a round object's own (sensing; the solver's disc is in drive)
    )


def scene_buffers(k: int, edges: int, static_circles: int) -> tuple[np.ndarray, ...]:
    """Buffers for pucks.scene_into: at most ``k`` objects' and the obstacles' circles."""
    nc = k + static_circles
    return (
        np.zeros((nc, 2)),
        np.zeros(nc),
        np.zeros(nc, dtype=np.int64),
        np.zeros(nc, dtype=np.bool_),
        np.zeros((edges, 4)),
    )
