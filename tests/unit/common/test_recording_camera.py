"""A real run's recording carries the camera's frames and the tracked poses: the mcap
library reads them back, Foxglove's schemas name them, and the comparison with a
simulated run takes the robot's track from the camera."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader

from common.recording import schema as s
from common.recording.compare import compare
from common.recording.reader import read_recording
from common.recording.writer import RecordingWriter, pose_record
from common.sim2d import maps
from common.world import packing

AGENT = "k1"  # maps/empty.json's Khepera
REPO = Path(__file__).resolve().parents[3]


def info(start: float, world: str) -> s.RunInfo:
    return s.RunInfo(
        ctx="robots", world=world, agent=AGENT, user="ana", request_id=f"{world}-1",
        mode="deploy", start=start, planned_end=start + 10,
    )  # fmt: skip


def frame_at(x: float, y: float, t: float) -> s.FrameRecord:
    return s.FrameRecord(
        tick=int(t * 50), sim_time=t, layout=0, agents=1, rows=[AGENT], x=[x], y=[y],
        heading=[0.0], fingers=[0],
    )  # fmt: skip


def write_run(path: Path, world: str, *, camera: bool, drift: float = 0.0) -> None:
    start = 1000.0
    writer = RecordingWriter(path, info(start, world))
    writer.write(
        s.SNAPSHOT, packing.snapshot(maps.load_map(REPO / "maps" / "empty.json", name=world)), start
    )
    jpeg = cv2.imencode(".jpg", np.full((48, 64, 3), 128, np.uint8))[1].tobytes()
    for i in range(20):
        t = start + i * 0.5
        true_x = 200.0 + 20 * i
        writer.write(s.FRAME, frame_at(true_x + drift * i, 500.0, i * 0.5), t)
        writer.write(s.pose_topic(AGENT), pose_record(true_x + drift * i, 500.0, 0.0, t), t)
        if camera:
            tracked = s.TrackedRecord(
                camera="real1-cam", robots=[s.TrackedRobotRecord(AGENT, true_x, 500.0, 0.0)]
            )
            writer.write(s.TRACKED, tracked, t)
            writer.write(
                s.camera_topic("real1-cam"),
                s.CompressedImage(s.stamp(t), "camera/real1-cam", jpeg, "jpeg"),
                t,
            )
    writer.finish(s.RunEnd(status="finished", reason="its slot ended", at=start + 10))


def test_the_mcap_library_reads_the_video_and_the_tracked_poses(tmp_path: Path) -> None:
    path = tmp_path / "real.mcap"
    write_run(path, "real1", camera=True)
    schemas, images, tracked = {}, 0, 0
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            schemas[channel.topic] = schema.name
            if channel.topic == "/camera/real1-cam/image":
                image = json.loads(message.data)
                assert image["format"] == "jpeg"
                decoded = cv2.imdecode(
                    np.frombuffer(__import__("base64").b64decode(image["data"]), np.uint8),
                    cv2.IMREAD_COLOR,
                )
                assert decoded.shape == (48, 64, 3)
                images += 1
            elif channel.topic == "/tracking/poses":
                record = json.loads(message.data)
                assert record["robots"][0]["agent"] == AGENT
                tracked += 1
    assert (images, tracked) == (20, 20)
    assert schemas["/camera/real1-cam/image"] == "foxglove.CompressedImage"
    back = read_recording(path)
    assert len(back.images) == 20 and len(back.tracked) == 20


def test_a_real_run_is_compared_by_where_the_camera_saw_its_robot(tmp_path: Path) -> None:
    sim, real = tmp_path / "sim.mcap", tmp_path / "real.mcap"
    write_run(sim, "arena1", camera=False)
    # The real robot's odometry drifts 3 mm a step from where the camera sees it.
    write_run(real, "real1", camera=True, drift=3.0)
    result = compare(read_recording(sim), read_recording(real))
    assert (result.a.poses_from, result.b.poses_from) == ("frames", "camera")
    assert math.isclose(result.final_pose_error_mm, 0.0, abs_tol=0.5)
    real_by_frames = tmp_path / "real-no-camera.mcap"
    write_run(real_by_frames, "real1", camera=False, drift=3.0)
    drifted = compare(read_recording(sim), read_recording(real_by_frames))
    assert drifted.b.poses_from == "frames"
    assert drifted.final_pose_error_mm > 50.0


def test_a_replay_lays_the_floor_video_of_its_cursor(tmp_path: Path) -> None:
    """The recorded floor view at the replay's cursor: the frame taken last before it."""
    from common.recording.replay import Player, Timeline
    from viewers.web.replay import ReplayFeed

    path = tmp_path / "real.mcap"
    start = 1000.0
    writer = RecordingWriter(path, info(start, "real1"))
    writer.write(
        s.SNAPSHOT,
        packing.snapshot(maps.load_map(REPO / "maps" / "empty.json", name="real1")),
        start,
    )
    for i in range(10):
        t = start + i * 0.5
        writer.write(s.FRAME, frame_at(200.0 + 20 * i, 500.0, i * 0.5), t)
        shade = np.full((50, 50, 3), 20 * i, np.uint8)  # frame i is grey level 20 i
        jpeg = cv2.imencode(".jpg", shade)[1].tobytes()
        topic = s.camera_topic("real1-cam", "floor")
        writer.write(topic, s.CompressedImage(s.stamp(t), topic.strip("/"), jpeg, "jpeg"), t)
    writer.finish(s.RunEnd(status="finished", reason="its slot ended", at=start + 5))
    player = Player(Timeline(read_recording(path)))
    camera = ReplayFeed(player).camera()
    assert camera is not None
    player.seek(2.2)  # between frames 4 (2.0 s) and 5 (2.5 s)
    shown = camera.floor()
    assert shown is not None and shown[0] == 4 and shown[2] == start + 2.0
    assert abs(int(shown[1].mean()) - 80) <= 2  # grey level 20 * 4
    player.seek(0.0)
    assert camera.floor() is not None and camera.floor()[0] == 0  # type: ignore[index]


def test_a_simulated_run_has_no_video_to_replay(tmp_path: Path) -> None:
    from common.recording.replay import Player, Timeline
    from viewers.web.replay import ReplayFeed

    path = tmp_path / "sim.mcap"
    write_run(path, "arena1", camera=False)
    assert ReplayFeed(Player(Timeline(read_recording(path)))).camera() is None
