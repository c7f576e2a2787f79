"""What a controller sees of a SensorSample from the network (common/world/remote_robot.py)."""

from __future__ import annotations

from common.messages import GripperReading, SensorSample
from common.world.remote_robot import state_from_sample


def _sample(**kw: object) -> SensorSample:
    fields = dict(
        world="w",
        agent="k0",
        tick=3,
        sim_time=0.06,
        proximity=[5] * 8,
        ambient=[400] * 8,
        counters=(10, -4),
        speeds=(3, 3),
        leds=[1, 0],
    )
    fields.update(kw)
    return SensorSample(**fields)  # type: ignore[arg-type]


def test_readings_pass_through_unchanged_when_in_range() -> None:
    state = state_from_sample(_sample(proximity=[0, 1, 2, 3, 1020, 1021, 1022, 1023]))
    assert state.proximity == (0, 1, 2, 3, 1020, 1021, 1022, 1023)
    assert state.ambient == (400,) * 8 and state.counters == (10, -4) and state.time == 0.06
    assert state.leds == (True, False)


def test_out_of_range_and_missing_readings_are_clamped_and_padded() -> None:
    # Another robot type may report fewer sensors, a faulty one values out of range.
    state = state_from_sample(_sample(proximity=[-7, 5000, 12], ambient=[2**40] * 9))
    assert state.proximity == (0, 1023, 12, 0, 0, 0, 0, 0)
    assert state.ambient == (1023,) * 8


def test_gripper_reading_maps_to_the_controller_fields() -> None:
    gripper = GripperReading(arm=250, fingers="holding", presence=255, resistivity=40)
    state = state_from_sample(_sample(gripper=gripper))
    assert state.arm == 250 and state.gripper_closed and state.object_present
    assert state.resistivity == 40
