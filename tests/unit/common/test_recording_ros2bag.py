"""A recording as a ROS 2 bag: rosbags' reader (what ROS 2 tools' formats are checked
with here) finds every topic with its ROS 2 type, as many messages as the recording
holds, at the recording's times, with the values converted to ROS units."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from common.recording import read_recording
from common.recording import schema as s
from common.recording.ros2bag import body_speeds, drive_of, write_bag
from common.recording.writer import RecordingWriter, pose_record
from common.sim2d import maps
from common.world import packing

AGENT = "k1"  # maps/empty.json's Khepera
REPO = Path(__file__).resolve().parents[3]
START = 1_700_000_000.25
JPEG = b"\xff\xd8\xff\xe0 a small jpeg \xff\xd9"


def write_run(path: Path) -> None:
    info = s.RunInfo(
        ctx="robots", world="real1", agent=AGENT, user="ana", request_id="real1-1",
        mode="deploy", start=START, planned_end=START + 10,
    )  # fmt: skip
    writer = RecordingWriter(path, info)
    snapshot = packing.snapshot(maps.load_map(REPO / "maps" / "empty.json", name="real1"))
    writer.write(s.SNAPSHOT, snapshot, START)
    for i in range(20):
        t = START + 0.05 * (i + 1)
        x, heading = 200.0 + 4 * i, 0.1 * i
        frame = s.FrameRecord(
            tick=i, sim_time=0.05 * i, layout=0, agents=1, rows=[AGENT], x=[x], y=[500.0],
            heading=[heading], fingers=[0],
        )  # fmt: skip
        writer.write(s.FRAME, frame, t)
        writer.write(s.pose_topic(AGENT), pose_record(x, 500.0, heading, t), t)
        sample = s.SampleRecord(
            agent=AGENT, tick=i, sim_time=0.05 * i, proximity=[i] * 8, ambient=[500] * 8,
            counters=(10 * i, 12 * i), speeds=(10, 12), leds=[0, 0],
        )  # fmt: skip
        writer.write(s.sensors_topic(AGENT), sample, t + 0.001)
        command = s.CommandRecord(agent=AGENT, sender="ana", auth="mac", speeds=(10, 10))
        writer.write(s.commands_topic(AGENT), command, t + 0.002)
        if i % 5 == 0:
            leds = s.CommandRecord(agent=AGENT, sender="ana", auth="mac", leds=[True, False])
            writer.write(s.commands_topic(AGENT), leds, t + 0.003)
            image = s.CompressedImage(s.stamp(t), "camera/real1-cam/image", JPEG, "jpeg")
            writer.write(s.camera_topic("real1-cam"), image, t)
            writer.write(s.tracked_topic(AGENT), pose_record(x + 1, 501.0, heading, t), t)
    line = s.LogLine(s.stamp(START + 1), 4, "boom", "controller", "c.py", 9)
    writer.write(s.OUTPUT, line, START + 1)
    writer.finish(s.RunEnd(status="finished", reason="its slot ended", at=START + 10))


def test_every_topic_type_count_and_time_of_a_recording_is_in_its_bag(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_run(path)
    recording = read_recording(path)
    export = write_bag(recording, tmp_path / "bag")
    expected = {
        "/tf": ("tf2_msgs/msg/TFMessage", [r.t for r in recording.frames]),
        "/k1/odom": ("nav_msgs/msg/Odometry", [r.t for r in recording.poses]),
        "/k1/ir/proximity": ("std_msgs/msg/Float32MultiArray", [r.t for r in recording.samples]),
        "/k1/ir/ambient": ("std_msgs/msg/Float32MultiArray", [r.t for r in recording.samples]),
        "/k1/joint_states": ("sensor_msgs/msg/JointState", [r.t for r in recording.samples]),
        "/k1/cmd_vel": (
            "geometry_msgs/msg/Twist",
            [r.t for r in recording.commands if r.record.speeds is not None],
        ),
        "/k1/tracked": ("geometry_msgs/msg/PoseStamped", [r.t for r in recording.tracked_poses]),
        "/camera/real1-cam/image/compressed": (
            "sensor_msgs/msg/CompressedImage",
            [r.t for r in recording.images],
        ),
        "/rosout": ("rcl_interfaces/msg/Log", [r.t for r in recording.output]),
    }
    assert export.types == {topic: kind for topic, (kind, _) in expected.items()}
    assert export.counts == {topic: len(times) for topic, (_, times) in expected.items()}
    assert (export.counts["/k1/odom"], export.counts["/k1/cmd_vel"]) == (20, 20)
    assert export.notes == []

    store = get_typestore(Stores.ROS2_JAZZY)
    messages: dict[str, list[tuple[float, Any]]] = {}
    with AnyReader([tmp_path / "bag"], default_typestore=store) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == export.types
        for connection, timestamp, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            messages.setdefault(connection.topic, []).append((timestamp / 1e9, message))
    for topic, (_, times) in expected.items():
        got = [t for t, _ in messages[topic]]
        assert np.allclose(got, times, rtol=0, atol=1e-6), topic

    # the values, in ROS units
    odom = messages["/k1/odom"][5][1]
    assert odom.header.frame_id == "arena" and odom.child_frame_id == "k1/base_link"
    assert math.isclose(odom.pose.pose.position.x, 0.220, abs_tol=1e-9)
    assert math.isclose(odom.twist.twist.angular.z, 0.1 / 0.05, rel_tol=1e-3)
    tf = messages["/tf"][5][1].transforms[0]
    assert tf.child_frame_id == "k1/base_link" and math.isclose(tf.transform.translation.x, 0.22)
    ir = messages["/k1/ir/proximity"][7][1]
    assert list(ir.data) == [7.0] * 8 and ir.layout.dim[0].size == 8
    wheels = messages["/k1/joint_states"][3][1]
    assert list(wheels.position) == [30.0, 36.0] and list(wheels.velocity) == [10.0, 12.0]
    twist = messages["/k1/cmd_vel"][0][1]
    # Khepera: 0.08 mm a pulse per 10 ms, so 10 units are 0.08 m/s
    assert math.isclose(twist.linear.x, 0.08) and twist.angular.z == 0.0
    image = messages["/camera/real1-cam/image/compressed"][0][1]
    assert bytes(image.data) == JPEG and image.format == "jpeg"
    log = messages["/rosout"][0][1]
    assert (log.level, log.msg, log.line) == (40, "boom", 9)


def test_a_bag_is_never_written_over(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_run(path)
    (tmp_path / "bag").mkdir()
    with pytest.raises(FileExistsError, match="new directory"):
        write_bag(read_recording(path), tmp_path / "bag")


def test_the_wheel_speeds_are_the_bodys_speeds_of_the_runs_robot_type(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_run(path)
    drive = drive_of(read_recording(path))
    assert drive is not None and drive.wheel_base_mm == 53.0  # the Khepera's
    forward, turning = body_speeds(drive, -10, 10)
    assert forward == 0.0
    assert math.isclose(turning, 2 * 0.08 / 0.053)


def test_wart_record_export_writes_the_bag_of_a_file_and_says_what_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from services.commands import record

    path = tmp_path / "run.mcap"
    write_run(path)
    assert record.main(["export", str(path)]) == 0
    said = capsys.readouterr().out
    assert f"wrote {tmp_path / 'run'}/ (ROS 2 bag, MCAP storage): /camera/" in said
    assert "/k1/odom 20" in said
    with AnyReader([tmp_path / "run"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        # 20 each of /tf, odom, cmd_vel and the three sensor topics; 4 tracked, 4 images, 1 log
        assert r.message_count == 6 * 20 + 4 + 4 + 1
    # again: the bag is never written over; a file that is not a recording is said so
    assert record.main(["export", str(path)]) == 2
    (tmp_path / "notes.mcap").write_text("not a recording")
    assert record.main(["export", str(tmp_path / "notes.mcap"), "-o", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err
    assert "exists: a bag is written to a new directory" in err
    assert "cannot write the bag: " in err and "is not an MCAP recording" in err
    assert not (tmp_path / "b").exists()
    assert record.main(["list"]) == 2
    assert "list needs --context and --user" in capsys.readouterr().err
