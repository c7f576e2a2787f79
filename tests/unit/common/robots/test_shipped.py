"""The shipped robot files are the Khepera and e-puck the engine had in Python, bit for bit.

The files compile to the very specs common/sim2d/agents/khepera.py and epuck.py
write (every field equal), and a seeded world of each gives the same poses
and readings, to the last bit, as a world of the Python-written type: the
engine, its kernels and its noise are unchanged.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from common.robots import registry
from common.sim2d.agents import agent_type, epuck, khepera
from common.sim2d.entities import ShapeSpec
from common.sim2d.specs import AgentTypeSpec
from common.sim2d.world import World


@pytest.mark.parametrize("reference", [khepera.SPEC, epuck.SPEC], ids=lambda s: s.name)
def test_the_shipped_files_compile_to_the_python_specs(reference: AgentTypeSpec) -> None:
    compiled = registry.build(plugins=False).robots[reference.name]
    assert compiled.source == f"{reference.name}.toml"
    assert [c.name for c in compiled.components][:4] == ["body", "drive", "proximity", "ambient"]
    assert dataclasses.replace(compiled, components=(), source="") == reference


def _run(spec: AgentTypeSpec, drive: str) -> tuple[np.ndarray, ...]:
    world = World(800, 600, seed=7, drive=drive)
    world.add_obstacle("wall", ShapeSpec.box(200, 30), 400, 300)
    world.add_obstacle("post", ShapeSpec.circle(25), 200, 420)
    world.add_light("lamp", 600, 450, radius_mm=400)
    for i in range(6):
        world.add_agent(f"r{i}", spec, 120 + 110 * i, 150 + 40 * (i % 2), 0.3 * i)
    world.cmd[:] = [[40, 60], [60, 40], [50, 50], [-30, 30], [70, 65], [20, 80]]
    poses, prox, amb = [], [], []
    for _ in range(150):
        world.step()
        poses.append(world.agent_pose.copy())
        prox.append(world.proximity.copy())
        amb.append(world.ambient.copy())
    return np.array(poses), np.array(prox), np.array(amb), world.counters.copy()


@pytest.mark.parametrize("drive", ["joints", "discs"])
@pytest.mark.parametrize("reference", [khepera.SPEC, epuck.SPEC], ids=lambda s: s.name)
def test_a_seeded_run_of_the_file_type_is_the_python_types_bit_for_bit(
    reference: AgentTypeSpec, drive: str
) -> None:
    from_file = agent_type(reference.name)
    assert from_file is not reference  # really the file's
    if drive == "discs" and reference.gripper is not None:
        pass  # the discs drive runs robots without objects: grippers fitted, unused
    want = _run(reference, drive)
    got = _run(from_file, drive)
    for a, b in zip(want, got, strict=True):
        assert a.shape == b.shape
        assert np.array_equal(a, b)
    assert want[1].max() > 0  # the robots saw something: the comparison means something
    assert math.isfinite(float(want[0].sum()))
