"""Sensor noise drawn inside the sensing kernel (issue 22): seeded, and Gaussian.

The kernel derives each sensor's noise from a per-pass key (one raw draw of the
world's generator), the agent's slot and the sensor (kernels.normal: SplitMix64
words through numpy's 256-layer ziggurat). These tests check that the draws are
standard normal, that streams are independent of each other, that a seed
reproduces the readings, and that each reading keeps the documented noise
model: proximity v * (1 + 3 % z1) + 2 counts z2, ambient v * (1 + 2 % z).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.sim2d import kernels, noise, packs
from common.sim2d.agents import agent_type
from common.sim2d.entities import ShapeSpec
from common.sim2d.world import World

KHEPERA = agent_type("khepera")


def _normal_cdf(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.vectorize(math.erf)(x / math.sqrt(2.0)))


def test_the_draws_are_standard_normal() -> None:
    z = kernels.normals(np.uint64(0x5EED), 0, 200_000)
    n = len(z)
    assert abs(z.mean()) < 5 / math.sqrt(n)
    assert z.std() == pytest.approx(1.0, abs=0.01)
    assert (z**3).mean() == pytest.approx(0.0, abs=0.03)
    assert (z**4).mean() == pytest.approx(3.0, abs=0.08)
    # The tail beyond the ziggurat's base (R = 3.654) and a wedge-heavy band.
    for lo, hi in ((1.0, 2.0), (2.5, 3.0), (noise._ZIG_R, np.inf)):
        want = 2 * (_normal_cdf(np.array([hi]))[0] - _normal_cdf(np.array([lo]))[0])
        got = ((np.abs(z) >= lo) & (np.abs(z) < hi)).mean()
        assert got == pytest.approx(want, abs=5 * math.sqrt(want / n) + 1e-5), (lo, hi)
    # Kolmogorov-Smirnov against the normal CDF: D below the 0.1 % critical value.
    s = np.sort(z)
    cdf = _normal_cdf(s)
    d = max((np.arange(1, n + 1) / n - cdf).max(), (cdf - np.arange(n) / n).max())
    assert d < 1.95 / math.sqrt(n)


def test_streams_and_keys_are_reproducible_and_independent() -> None:
    key = np.uint64(2**63 + 12345)  # keys use all 64 bits
    a = kernels.normals(key, 1000, 50_000)
    assert np.array_equal(a, kernels.normals(key, 1000, 50_000))
    # One stream is the same value whatever batch it is asked in (any thread split).
    assert kernels.normals(key, 1777, 1)[0] == a[777]
    # A plain int key (below 2**63) draws what the same key as numpy's uint64 does.
    assert np.array_equal(kernels.normals(12345, 0, 100), kernels.normals(np.uint64(12345), 0, 100))
    other = kernels.normals(np.uint64(2**63 + 12346), 1000, 50_000)
    assert not np.array_equal(a, other)
    # Neighbouring streams (a robot's sensors) and neighbouring keys (passes) are
    # uncorrelated.
    for x, y in ((a[:-1], a[1:]), (a, other), (a[:-8], a[8:])):
        assert abs(np.corrcoef(x, y)[0, 1]) < 5 / math.sqrt(len(x))


def _scene(seed: int) -> World:
    """A robot 10 mm from a wall, facing it; one 150 mm from a lamp; one in the dark."""
    world = World(1200.0, 800.0, seed=seed, tick_s=0.01, sensor_period_s=0.02)
    world.add_obstacle("wall", ShapeSpec.box(40, 400), 700.0, 400.0)
    world.add_agent("near", KHEPERA, 680.0 - 25.0 - 10.0, 400.0, 0.0)
    world.add_agent("lit", KHEPERA, 200.0, 150.0, 0.0)
    world.add_agent("dark", KHEPERA, 200.0, 650.0, 0.0)
    world.add_light("lamp", 350.0, 150.0, radius_mm=300.0)
    return world


def test_same_seed_same_readings_other_seed_other_readings() -> None:
    def passes(seed: int) -> np.ndarray:
        world = _scene(seed)
        rows = []
        for _ in range(20):
            world.sense()
            rows.append(np.concatenate([world.proximity.ravel(), world.ambient.ravel()]))
        return np.array(rows)

    assert np.array_equal(passes(3), passes(3))
    assert not np.array_equal(passes(3), passes(4))


def _noiseless(world: World) -> tuple[np.ndarray, np.ndarray]:
    """One pass with every noise coefficient 0: the readings the noise is added to."""
    packed, scene, moving = world.sensors.packs(world, world.sim_time)
    tables: list[object] = list(packed)
    f = np.array(tables[3], copy=True)
    f[:, packs.F_PROX_NOISE_FRACTION] = 0.0
    f[:, packs.F_AMB_NOISE_FRACTION] = 0.0
    tables[3] = f
    tables[11] = np.zeros_like(tables[11])  # each IR sensor's additive noise
    out = (
        np.zeros_like(world.proximity),
        np.zeros_like(world.ambient),
        np.zeros_like(world.presence),
    )
    kernels.sense((world.agent_pose, world.arm, world.holding()), tuple(tables), scene, moving, out)
    return out[0], out[1]


def test_each_reading_keeps_the_documented_noise_model() -> None:
    world = _scene(5)
    prox0, amb0 = _noiseless(world)
    near, lit, dark = (world.agent_slot(a) for a in ("near", "lit", "dark"))
    assert 300 < prox0[near, 2] < 900, "the wall is not where the test wants it"
    assert amb0[lit].min() < 400 and (amb0[dark] == 500).all()
    passes = 3000
    prox = np.empty((passes, *world.proximity.shape))
    amb = np.empty((passes, *world.ambient.shape))
    for i in range(passes):
        world.sense()
        prox[i], amb[i] = world.proximity, world.ambient
    p = KHEPERA.proximity
    a = KHEPERA.ambient
    # Proximity: mean v, sd sqrt((3 % of v)^2 + 2^2) (v * (1 + nf z1) + nc z2).
    for j in (2, 3):
        v = float(prox0[near, j])
        sd = math.hypot(v * p.noise_fraction, p.noise_counts)
        got = prox[:, near, j]
        assert got.mean() == pytest.approx(v, abs=5 * sd / math.sqrt(passes) + 0.5)
        assert got.std() == pytest.approx(sd, rel=0.06)
    # Ambient: mean v, sd 2 % of v, in the dark and under the lamp.
    for slot, j in ((dark, 0), (dark, 5), (lit, int(np.argmin(amb0[lit])))):
        v = float(amb0[slot, j])
        sd = v * a.noise_fraction
        got = amb[:, slot, j]
        assert got.mean() == pytest.approx(v, abs=5 * sd / math.sqrt(passes) + 0.5)
        assert got.std() == pytest.approx(sd, rel=0.06)
    # Sensors of one robot are independent of each other.
    assert abs(np.corrcoef(amb[:, dark, 0], amb[:, dark, 1])[0, 1]) < 0.1


@pytest.mark.parametrize("half_deg", [60.0, 30.0, 90.0, 170.0])
def test_the_trig_free_ambient_cone_equals_the_angle_formula(half_deg: float) -> None:
    # kernels.ambient_gain against the formula it replaced: the bearing from two
    # atan2, wrapped, then cos(1.5 * bearing) inside the cone, on random poses.
    rng = np.random.default_rng(int(half_deg))
    half = math.radians(half_deg)
    cos_half = math.cos(half)
    checked = inside = 0
    for vx, vy, axis in rng.uniform([-500, -500, -10], [500, 500, 10], size=(20_000, 3)):
        d = math.sqrt(vx * vx + vy * vy)
        raw = math.atan2(vy, vx) - axis
        bearing = math.atan2(math.sin(raw), math.cos(raw))
        if abs(abs(bearing) - half) < 1e-9:
            continue  # on the cone's edge: either side is within rounding
        old = math.cos(1.5 * bearing) if abs(bearing) < half else 0.0
        new = kernels.ambient_gain(vx, vy, d, math.cos(axis), math.sin(axis), cos_half)
        assert new == pytest.approx(old, abs=1e-12), (vx, vy, axis)
        checked += 1
        inside += abs(bearing) < half
    assert checked > 19_000 and 0.05 * checked < inside < checked
