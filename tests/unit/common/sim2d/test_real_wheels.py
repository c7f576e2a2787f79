"""A Khepera whose wheels slip and obey late (a real robot's twin) in a Sim2D world.

Its robot file's drive sets each wheel's scale, the wheel base and the command
latency; the world moves it as the twin's motion model says (common/twin/motion.py),
counts the wheels' own turn on its counters (so its odometry drifts as the real
robot's does) and reads its speeds back as commanded. A datasheet Khepera in the
same world is not touched (its trajectories, bit for bit: bench/drive_hashes.py).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from common.sim2d import maps
from common.sim2d.world import World
from common.twin.motion import Drive, predict
from common.twin.twinfile import SHIPPED_KHEPERA

TWIN = Drive(scale_left=0.95, scale_right=1.02, wheel_base_mm=56.0, latency_s=0.06)
# (from s, left, right): straight on, a spin, a stop, a curve.
COMMANDS = [(0.0, 20.0, 20.0), (2.0, -8.0, 8.0), (3.0, 0.0, 0.0), (3.5, 15.0, 9.0)]


def world(drive: str = "discs") -> World:
    twin = SHIPPED_KHEPERA.read_text().replace('name = "khepera"', 'name = "twin-k1"')
    twin = twin.replace(
        "wheel_base_mm = 53.0",
        f"wheel_base_mm = {TWIN.wheel_base_mm}\nwheel_scale = [{TWIN.scale_left}, "
        f"{TWIN.scale_right}]\nlatency_s = {TWIN.latency_s}",
    )
    room = {
        "format": "wart-map", "version": 1, "name": "t", "arena": {"width": 3000, "height": 3000},
        "robot_types": {"twin-k1": twin},
        "agents": [{"id": "k1", "type": "twin-k1", "x": 1000, "y": 1500},
                   {"id": "k0", "type": "khepera", "x": 2000, "y": 1500}],
    }  # fmt: skip
    parsed = maps.parse_map(json.dumps(room), source="t")
    return maps.build_world(parsed, name="t", drive=drive, tick_s=0.01)


def test_a_twins_khepera_moves_as_its_motion_model_says() -> None:
    w = world()
    start = w.agent_pose.copy()
    steps = 0
    for at, left, right in [*COMMANDS, (5.0, 0.0, 0.0)]:
        while w.sim_time < at - 1e-9:
            w.step()
            steps += 1
        w.set_speeds(0, left, right)
        w.set_speeds(1, left, right)
        assert tuple(w.cmd[0]) == (left, right)  # read back as commanded, not as slipped
    got = w.agent_pose
    commands = np.array(COMMANDS, dtype=float)
    want = predict(TWIN, commands, start[:1], np.zeros(1), np.array([w.sim_time]))[0]
    datasheet = predict(Drive(), commands, start, np.zeros(2), np.full(2, w.sim_time))
    near = 1.5  # mm after 5 s
    assert np.hypot(*(got[0, :2] - want[:2])) < near, (got[0], want)
    assert abs(got[0, 2] - want[2]) < 0.02
    assert np.hypot(*(got[1, :2] - datasheet[1, :2])) < near  # its neighbour: the datasheet's
    assert np.hypot(*(got[0, :2] - datasheet[0, :2])) > 10 * near  # not the datasheet's path
    # The counters count each wheel's turn (its commands, obeyed late), not the motion.
    pulses = w.tick_s * w.tables.pulses_per_s_per_unit[0]
    obeyed = commands.copy()
    obeyed[:, 0] += TWIN.latency_s
    turned = [
        sum(v * (min(t1, w.sim_time) - max(t0, 0)) for (t0, *_), t1, v in zip(
            obeyed, [*obeyed[1:, 0], w.sim_time], obeyed[:, 1 + wheel], strict=True))
        for wheel in (0, 1)
    ]  # fmt: skip
    assert w.counters[0] == pytest.approx(np.array(turned) * pulses / w.tick_s, abs=30)


def test_a_twins_khepera_obeys_a_command_only_after_its_latency() -> None:
    w = world("discs")
    w.step()
    x0 = w.agent_pose[0, 0]
    w.set_speeds(0, 20, 20)
    for _ in range(5):  # 50 ms: less than the 60 ms latency
        w.step()
    assert w.agent_pose[0, 0] == x0
    w.step()
    w.step()
    assert w.agent_pose[0, 0] > x0
