"""A world keeps the memory its ticks free (common/sim2d/heap.py).

What a user relies on: a swarm's tick, which allocates and frees arrays of a
few hundred kilobytes, does not go back to the kernel for fresh pages every
tick (at 10,000 robots that was 412 page faults and half of a drive tick).
Measured in a fresh process each time: malloc's settings are process-wide.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[4]

# Ticks of the discs drive's allocating kernel (discs.tick: new arrays every
# call, as the general path makes them) on 10,000 robots spread over a swarm's
# arena, after a World is made; prints the minor page faults per tick.
_TICKS = """
import json, resource, sys
import numpy as np
from common.sim2d import discs, heap, pucks
from common.sim2d.world import World

World(100.0, 100.0)
n, side = 10_000, 8_700.0
rng = np.random.default_rng(3)
pose = np.column_stack([rng.uniform(50, side - 50, (n, 2)), rng.uniform(-3, 3, n)])
cmd = rng.uniform(-10, 10, (n, 2))
one = np.ones(n)
scene = (np.zeros((0, 4)), np.zeros(2, dtype=np.int64), np.zeros(0, dtype=np.int64), 1, 1,
         side, np.zeros((0, 4)), np.zeros((0, 2)), np.zeros(0))
circles = discs.bin_circles(np.zeros((0, 2)), np.zeros(0), 1, 1, side)
drive = (8.0 * one, 53.0 * one, one, 27.5 * one, 80.0 * one)
counters, arm = np.zeros((n, 2)), np.zeros(n)
args = (drive, scene, circles, (side, side, 0.01), 1, pucks.objects_table(0, n))
for _ in range(5):
    pose, _vel = discs.tick((pose, cmd, counters, arm), *args)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(40):
    pose, _vel = discs.tick((pose, cmd, counters, arm), *args)
faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 40
print(json.dumps({"set": heap.keep_freed_memory(), "faults_per_tick": faults}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_a_swarms_ticks_reuse_the_memory_they_free() -> None:
    run = subprocess.run(
        [sys.executable, "-c", _TICKS],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["set"], "malloc's thresholds were not set"
    # Without the settings this was about 400 a tick (every tick's arrays on fresh pages).
    assert result["faults_per_tick"] < 20, result
