"""SimBody: the emulated Khepera's body is a Sim2D Khepera (in-process, its own stepping thread)."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from common.sim2d.maps import MapError
from services.bridge.body import RobotBody
from services.bridge.firmware import Firmware
from services.bridge.main import parse_port
from services.bridge.service import agent_id_for
from services.bridge.simbody import SimBody
from tests.conftest import REPO, wait_for

EMPTY = REPO / "maps" / "empty.json"


@pytest.fixture
def sim() -> Iterator[SimBody]:
    with SimBody.from_map(EMPTY, seed=1) as body:
        yield body


def test_is_a_robot_body(sim: SimBody) -> None:
    assert isinstance(sim, RobotBody)
    assert sim.agent == "k1" and sim.pose() == (500.0, 500.0, 0.0)


def test_ir_rises_near_a_wall_and_stays_low_in_the_open(sim: SimBody) -> None:
    assert max(sim.proximity()) < 50, sim.proximity()
    sim.place(1000 - 27.5 - 8, 500, 0.0)  # facing the east wall from 8 mm
    front = sim.proximity()
    assert min(front[2], front[3]) > 150, front
    assert max(front[6], front[7]) < 50, front  # the back sensors see nothing
    assert all(300 < v <= 1023 for v in sim.ambient())  # no lamp: about 500


def test_speed_moves_the_body_and_counts_pulses(sim: SimBody) -> None:
    sim.set_speeds(20, 20)  # 160 mm/s
    wait_for(lambda: sim.pose()[0] > 530, 10, "the body to drive forward")
    assert sim.speed() == (20, 20)
    left, right = sim.counters()
    assert left > 300 and abs(left - right) <= 1
    sim.set_speeds(-10, 10)  # spin on the spot
    wait_for(lambda: abs(sim.pose()[2]) > 0.5, 10, "the body to turn")
    sim.reset()
    assert sim.speed() == (0, 0) and sim.counters() == (0, 0)


def test_position_control_stops_on_the_target(sim: SimBody) -> None:
    sim.set_counters(0, 0)
    sim.move_to(400, -400, (20, 20), (64, 64))
    wait_for(lambda: sim.motion_status()[0] == 1 and sim.motion_status()[3] == 1, 10, "on target")
    assert sim.counters() == (400, -400) and sim.speed() == (0, 0)


def test_gripper_arm_and_fingers(sim: SimBody) -> None:
    sim.set_arm(255)
    wait_for(lambda: sim.arm_position() == 255, 10, "the arm down")
    sim.set_grip(True)
    assert sim.finger_position() > 100 and sim.resistivity() == 255  # closed on nothing


def test_firmware_over_a_sim_body_answers_from_the_world(sim: SimBody) -> None:
    fw = Firmware(sim)
    assert fw.handle("D,10,-10\r") == b"d\r\n"
    assert fw.handle("E\r") == b"e,10,-10\r\n"
    assert fw.handle("N\r").startswith(b"n,") and fw.handle("N\r").count(b",") == 8


def test_calls_from_another_thread_while_it_steps(sim: SimBody) -> None:
    errors: list[BaseException] = []

    def hammer() -> None:
        try:
            for i in range(300):
                sim.set_speeds(i % 30, -(i % 30))
                sim.proximity()
                sim.counters()
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=hammer) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors and sim.ticks > 0


def test_a_starved_stepping_thread_leaves_the_robot_where_the_wall_clock_says(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A loaded host's stepping thread stalls (here: its truth file takes 0.4 s to write);
    # the robot is read meanwhile. It must have driven on as a real one does, not wait
    # for the thread and then leap (readings of a robot up to 0.5 s behind, stamped now,
    # stepped the fused pose back by tens of mm).
    stalled = threading.Event()

    def slow_write(path: Path, truth: object) -> None:
        if not stalled.is_set():
            stalled.set()
            time.sleep(0.4)

    monkeypatch.setattr("services.bridge.simbody.write_truth", slow_write)
    with SimBody.from_map(EMPTY, seed=1, truth=tmp_path / "truth.json") as body:
        body.set_speeds(20, 20)  # 160 mm/s
        assert stalled.wait(5.0)
        x0, started = body.pose()[0], time.monotonic()
        time.sleep(0.2)
        x1, took = body.pose()[0], time.monotonic() - started
    assert x1 - x0 > 0.6 * 160.0 * took, (x0, x1, took)


def test_bad_maps_and_agents_are_clear_errors(tmp_path: object) -> None:
    with pytest.raises(ValueError, match="no agent 'k9'"):
        SimBody.from_map(EMPTY, "k9")
    with pytest.raises(MapError):
        SimBody.from_map(REPO / "maps" / "no-such-map.json")


def test_agent_ids_and_port_arguments() -> None:
    assert agent_id_for("/dev/ttyUSB0") == "ttyUSB0"
    assert agent_id_for("/dev/serial/by-id/usb-FTDI:x y") == "usb-FTDI-x-y"
    assert agent_id_for("/dev/ttyUSB0", ["ttyUSB0"]) == "ttyUSB0-2"
    spec = parse_port("/dev/ttyUSB0=k1@100,200,90", [])
    assert spec.agent == "k1" and spec.pose is not None
    assert (spec.pose.x, spec.pose.y) == (100, 200)
    assert spec.pose.heading == pytest.approx(math.pi / 2)
    assert parse_port("/tmp/khepera0", []).agent == "khepera0"
    for bad in ("=k1", "/a=bad/id", "/a=k1@1,2", "/a=k1@x,y,z", "/a=k1@nan,1,1"):
        with pytest.raises(ValueError):
            parse_port(bad, [])
    with pytest.raises(ValueError, match="twice"):
        parse_port("/b=k1", ["k1"])


def test_slipping_wheels_make_odometry_overstate_and_turn(tmp_path: Path) -> None:
    """With slip the counters count the wheels' turn, the robot moves less and curves:
    the drift a camera has to correct (and the truth file shows where it really is)."""
    from common.tracking.truth import read_truth
    from services.bridge.odometry import Odometry

    truth = tmp_path / "truth.json"
    with SimBody.from_map(EMPTY, seed=1, slip=0.04, truth=truth) as body:
        body.place(200, 500, 0.0)
        body.set_counters(0, 0)
        body.set_speeds(10, 10)  # straight ahead, ~80 mm/s
        wait_for(lambda: body.pose()[0] > 420, 30.0, "k1 to drive 220 mm")
        body.set_speeds(0, 0)
        left, right = body.counters()
        x, y, heading = body.pose()
        seen = read_truth(truth)
    odometry = Odometry(0.08, 53.0)
    odometry.update(0, 0, 0.0)
    counted = odometry.update(left, right, 1.0)
    travelled = math.hypot(x - 200, y - 500)
    assert counted.x > travelled * 1.015  # the counters claim more than the robot drove
    assert abs(heading) > 0.005  # the left wheel slips more: it curves left of the odometry's line
    assert seen.robots["k1"][0] == pytest.approx(x, abs=30.0)  # written as it drove
