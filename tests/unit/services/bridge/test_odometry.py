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


def test_readings_bunched_by_a_busy_host_still_count_the_travel() -> None:
    # 0.52 s of an arc at 40/60 pulses read twice 0.1 s apart by the host's clock (the
    # first answer came late): the robot moved, its counters were not reset.
    odometry = Odometry(MM_PER_PULSE, WHEEL_BASE)
    odometry.update(0, 0, 0.0)
    pose = odometry.update(2099, 3148, 0.1)
    assert math.hypot(pose.x, pose.y) > 150


def test_a_jump_no_wheel_can_make_is_a_reset_and_keeps_the_pose() -> None:
    odometry = Odometry(MM_PER_PULSE, WHEEL_BASE)
    odometry.update(0, 0, 0.0)
    driven = odometry.update(60000, 60000, 10.0)  # 4.8 m in 10 s: a fast robot
    # Back to zero 0.1 s later: 60,000 pulses no wheel turns within the read delay.
    kept = odometry.update(0, 0, 10.1)
    assert driven.x == pytest.approx(4800.0)
    assert kept == driven
