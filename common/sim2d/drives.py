"""How a world's robots are driven: the names, for the World, the maps, the CLI and lab files.

Kept apart from world.py so a lab file can be checked without loading the
physics (pymunk, numba). What each drive does: common/sim2d/world.py and
docs/ARCHITECTURE.md, "Drives".
"""

from __future__ import annotations

DRIVES = ("joints", "velocity", "discs")
# Every world's drive unless told otherwise (World, load_map, wart engine, lab files):
# the discs drive, robots and movable objects as discs of one compiled solver.
# "joints" (chipmunk's constraints) stays for whoever wants them: no default uses it.
DEFAULT_DRIVE = "discs"
# The drives whose worlds can hold movable objects: all of them (the discs drive's
# are discs of its contact solver, common/sim2d/pucks.py).
OBJECT_DRIVES = DRIVES
