"""Every slot is recorded by its agent context (real engine, runner, context): read back, owned."""

from __future__ import annotations

import textwrap
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from common.client.agent_client import FINAL
from common.lab_errors import LabError
from common.recording import Recording, read_recording, summarize
from common.recording import schema as s
from tests.conftest import Procs, Router, needs_sandbox, wait_for
from tests.kit.agentkit import (
    CTX,
    agent_user,
    start_agent_lab,
)
from tests.kit.lab import PASSWORD, USERS, ProcessLab, module_lab

pytestmark = [pytest.mark.one_worker, needs_sandbox]
FLOATS = "std_msgs/msg/Float32MultiArray"
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "01_braitenberg.py"
RAISER = textwrap.dedent(
    """
    from common.controller import Controller, Khepera

    class Raiser(Controller):
        def do_work(self, robot: Khepera) -> None:
            robot.set_speeds(5, 5)
            if robot.proximity().values[0] >= 0:
                print("about to fail")
                raise RuntimeError("boom from the controller")
    """
).encode()


@pytest.fixture(scope="module")
def lab(module_router: Router, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessLab]:
    """One lab for the module. Recordings are kept per user: each test records as its own
    user (dave, bob, carol), so another's runs count neither in its listings nor its
    retention, and alice records nothing (the test of bob's runs checks she sees none)."""
    tmp = tmp_path_factory.mktemp("lab")
    with module_lab(module_router, tmp, users={**USERS, "dave": "student"}) as lab:
        start_agent_lab(lab, "--keep-recordings", "2", map_name="maze", slot=3.0)
        yield lab


def _recordings_dir(lab: ProcessLab) -> Path:
    return lab.state / "rooms" / "recordings" / CTX


def _wait_recorded(lab: ProcessLab, user: str, name: str) -> Path:
    path = _recordings_dir(lab) / user / f"{name}.mcap"
    summary = path.with_name(f"{name}.summary.json")
    wait_for(summary.exists, 20, f"the recording of {name}")
    return path


def test_a_slot_of_example_01_is_recorded_with_every_channel(
    lab: ProcessLab, tmp_path: Path
) -> None:
    with agent_user(lab, "dave") as dave:
        queued = dave.queue("k1", "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name)
        final = dave.wait_status(queued.request_id, FINAL, timeout=30)
        assert final is not None and final.status == "finished", final
        _wait_recorded(lab, "dave", queued.request_id)
        listing = dave.recordings()
        assert [r.name for r in listing.recordings] == [queued.request_id]
        assert listing.recordings[0].status == "finished"
        path = dave.download(queued.request_id, tmp_path / "run.mcap")
    rec = read_recording(path)
    assert rec.truncated == ""
    present = set(rec.channels)
    agent_topics = {s.pose_topic("k1"), s.sensors_topic("k1"), s.commands_topic("k1")}
    assert {s.RUN, s.END, s.SNAPSHOT, s.FRAME, s.OUTPUT, s.EVENTS, s.CHAT} | agent_topics <= present
    assert rec.info is not None and rec.info.agent == "k1" and rec.info.user == "dave"
    assert len(rec.frames) > 50 and len(rec.samples) > 20 and len(rec.commands) > 20
    assert {c.record.sender for c in rec.commands} == {"runner-svc"}
    assert rec.end is not None and rec.end.status == "finished"
    assert {e.record.kind for e in rec.events} >= {"running", "finished"}
    summary = summarize(rec)
    assert summary.distance_mm > 50, summary
    assert summary.moving_s > 0.5, summary
    assert summary.status == "finished"


def test_a_killed_run_says_how_it_ended_and_retention_keeps_two(
    lab: ProcessLab, tmp_path: Path
) -> None:
    with agent_user(lab, "bob") as bob, agent_user(lab, "ida") as ida:
        names = []
        # 1: the controller raises
        q = bob.queue("k2", "deploy", source=RAISER, filename="raiser.py")
        final = bob.wait_status(q.request_id, FINAL, timeout=30)
        assert final is not None
        names.append(q.request_id)
        raised = summarize(read_recording(_wait_recorded(lab, "bob", q.request_id)))
        assert raised.errors and raised.errors[0].kind == "RuntimeError", raised
        assert raised.errors[0].line == 9, raised.errors  # the raise, in raiser.py
        # 2: stopped by the context's owner
        q = bob.queue("k2", "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name)
        assert bob.wait_status(q.request_id, {"running"}, timeout=30) is not None
        ida.stop_agent("k2", "enough")
        final = bob.wait_status(q.request_id, FINAL, timeout=30)
        assert final is not None and final.status == "cancelled"
        names.append(q.request_id)
        stopped = read_recording(_wait_recorded(lab, "bob", q.request_id))
        assert stopped.end is not None and stopped.end.status == "cancelled"
        assert "stopped by ida" in stopped.end.reason
        # 3: a third run: the first (oldest) is removed, --keep-recordings 2
        q = bob.queue("k2", "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name)
        assert bob.wait_status(q.request_id, FINAL, timeout=30) is not None
        names.append(q.request_id)
        _wait_recorded(lab, "bob", q.request_id)
        wait_for(
            lambda: [r.name for r in bob.recordings().recordings] == names[1:],
            10,
            "the oldest recording removed",
        )
        assert not (_recordings_dir(lab) / "bob" / f"{names[0]}.mcap").exists()
        # the manager sees bob's; alice does not
        assert [r.name for r in ida.recordings("bob").recordings] == names[1:]
    with agent_user(lab, "alice") as alice:
        with pytest.raises(LabError, match=r"forbidden|may list"):
            alice.recordings("bob")
        with pytest.raises(LabError, match="not yours"):
            alice.download(names[2], tmp_path / "theirs.mcap")
        assert alice.recordings().recordings == []


def _check_the_bag(bag: Path, recording: Recording) -> None:
    """The ROS 2 bag of a real run, read back with rosbags: its robot's topics and types,
    as many messages as the recording has, at the recording's times."""
    assert recording.info is not None
    agent = recording.info.agent
    commands = [c.t for c in recording.commands if c.record.speeds is not None]
    expected = {
        "/tf": ("tf2_msgs/msg/TFMessage", [r.t for r in recording.frames]),
        f"/{agent}/odom": ("nav_msgs/msg/Odometry", [r.t for r in recording.poses]),
        f"/{agent}/ir/proximity": (FLOATS, [r.t for r in recording.samples]),
        f"/{agent}/ir/ambient": (FLOATS, [r.t for r in recording.samples]),
        f"/{agent}/joint_states": ("sensor_msgs/msg/JointState", [r.t for r in recording.samples]),
        f"/{agent}/cmd_vel": ("geometry_msgs/msg/Twist", commands),
        "/rosout": ("rcl_interfaces/msg/Log", [r.t for r in recording.output]),
    }
    times: dict[str, list[float]] = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for connection, timestamp, _raw in reader.messages():
            times.setdefault(connection.topic, []).append(timestamp / 1e9)
    assert types == {topic: kind for topic, (kind, moments) in expected.items() if moments}
    assert len(recording.frames) > 50 and len(commands) > 20
    for topic, (_, moments) in expected.items():
        assert np.allclose(times.get(topic, []), moments, rtol=0, atol=1e-6), topic


def test_wart_record_and_report_from_the_command_line(
    lab: ProcessLab, procs: Procs, tmp_path: Path
) -> None:
    with agent_user(lab, "carol") as carol:
        q = carol.queue("k1", "deploy", source=EXAMPLE.read_bytes(), filename=EXAMPLE.name)
        assert carol.wait_status(q.request_id, FINAL, timeout=30) is not None
        _wait_recorded(lab, "carol", q.request_id)
    common = ["--context", CTX, "--user", "carol", *lab.net_args()]
    env = {"WART_PASSWORD": PASSWORD}
    # Commands that do not need each other's results run at once (each is mostly imports).
    listed = procs.start("record-list", ["record", "list", *common], env=env)
    out = tmp_path / "carol.mcap"
    got = procs.start(
        "record-get", ["record", "get", q.request_id, "-o", str(out), *common], env=env
    )
    bag = tmp_path / "carol-bag"
    as_bag = ["record", "get", q.request_id, "--format", "rosbag2", "-o", str(bag), *common]
    got_bag = procs.start("record-get-rosbag2", as_bag, env=env)
    assert listed.popen.wait(30) == 0, listed.output()
    assert q.request_id in listed.output()
    assert got.popen.wait(30) == 0, got.output()
    assert got_bag.popen.wait(30) == 0, got_bag.output()
    _check_the_bag(bag, read_recording(out))
    report = procs.start("report", ["report", str(out)])
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(out.read_bytes()[:100])
    bad = procs.start("report-bad", ["report", str(cut)])
    assert report.popen.wait(30) == 0, report.output()
    assert "distance:" in report.output() and "ended:       finished" in report.output()
    assert bad.popen.wait(30) == 1
    assert "error:" in bad.output() and "Traceback" not in bad.output()
