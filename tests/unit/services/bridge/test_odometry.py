"""Odometry from the Khepera's position counters, however far apart they are read."""

from __future__ import annotations

import math

import pytest

from services.bridge.odometry import Odometry

MM_PER_PULSE, WHEEL_BASE = 0.08, 53.0


def arc(left: int, right: int, seconds: float) -> tuple[float, float, float]:
    """Where wheels at ``left``/``right`` pulses per 10 ms take a robot from the origin."""
    dl, dr = (v * 100 * seconds * MM_PER_PULSE for v in (left, right))
    d, dth = (dl + dr) / 2, (dr - dl) / WHEEL_BASE
    r = d / dth
    return r * math.sin(dth), r * (1 - math.cos(dth)), dth


@pytest.mark.parametrize("readings", [2, 3, 61])
def test_an_arc_ends_where_the_wheels_took_it_whether_read_often_or_seldom(readings: int) -> None:
    # 0.6 s at 40/60 pulses: 1.8 rad of turn. A busy host may read the counters
    # only at the start and the end.
    odometry = Odometry(MM_PER_PULSE, WHEEL_BASE)
    seconds = 0.6
    for i in range(readings):
        t = seconds * i / (readings - 1)
        pose = odometry.update(round(40 * 100 * t), round(60 * 100 * t), t)
    x, y, heading = arc(40, 60, seconds)
    assert pose.x == pytest.approx(x, abs=0.1)
    assert pose.y == pytest.approx(y, abs=0.1)
    assert pose.heading == pytest.approx(heading, abs=1e-3)


def test_straight_ahead_is_straight() -> None:
    odometry = Odometry(MM_PER_PULSE, WHEEL_BASE)
    odometry.update(0, 0, 0.0)
    pose = odometry.update(1000, 1000, 1.0)
    assert (pose.x, pose.y, pose.heading) == (pytest.approx(80.0), 0.0, 0.0)
