"""The readings of the robots' batched sensors (floor, range finder, bumper, a plugin's).

A robot type's :class:`common.sim2d.specs.PartSpec` entries are measured for
every robot that carries them at once, grouped by (type, part): one call of
the component's ``measure`` per group. Readings are computed when first read
at a tick and kept for the rest of it (a world without such parts never
computes anything, so the engine's tick is unchanged for the Khepera).
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np

Readings = dict[str, tuple[np.ndarray, np.ndarray]]  # "<type>/<part>" -> (slots, values)


def read_parts(world: Any) -> Readings:
    """Every batched part's readings at the world's current tick."""
    stamp = (world.tick, world.layout, len(world.agents))
    cached = world.__dict__.get("_part_readings")
    if cached is not None and cached[0] == stamp:
        return cached[1]
    groups: dict[str, tuple[Any, list[int]]] = {}
    for slot, agent in enumerate(world.agents):
        for part in agent.spec.parts:
            key = f"{agent.spec.name}/{part.name}"
            groups.setdefault(key, (part, []))[1].append(slot)
    out: Readings = {}
    for key, (part, slots) in groups.items():
        rows = np.array(slots, dtype=np.int64)
        seed = (int(world.seed) * 1_000_003 + world.tick) * 65_537 + zlib.crc32(key.encode())
        values = np.asarray(part.component.measure(world, rows, part.values, seed % 2**63))
        # Readings are integers on the wire (counts, mm, 0/1), clamped to 32 bits.
        values = np.clip(np.rint(values), -(2**31), 2**31 - 1).astype(np.int64)
        out[key] = (rows, values.reshape(len(rows), part.size))
    world.__dict__["_part_readings"] = (stamp, out)
    return out


def parts_of(world: Any, slots: list[int]) -> list[dict[str, list[int]]]:
    """For each slot, its parts' readings by part name (empty for a robot without any)."""
    agents = world.agents
    # Whether any robot of the world carries a batched sensor, kept per layout: the
    # engine asks for every driven robot each tick, and a Khepera world has none.
    stamp = (world.layout, len(agents))
    known = world.__dict__.get("_has_parts")
    if known is None or known[0] != stamp:
        known = world.__dict__["_has_parts"] = (stamp, any(a.spec.parts for a in agents))
    if not known[1]:
        return [{} for _ in slots]
    readings = read_parts(world)
    index: dict[str, dict[int, int]] = {
        key: {int(s): i for i, s in enumerate(rows)} for key, (rows, _) in readings.items()
    }
    out = []
    for slot in slots:
        spec = agents[slot].spec
        mine: dict[str, list[int]] = {}
        for part in spec.parts:
            key = f"{spec.name}/{part.name}"
            _rows, values = readings[key]
            mine[part.name] = values[index[key][slot]].tolist()
        out.append(mine)
    return out
