"""Recordings: written with the mcap library, read back typed, summarised; damage said clearly."""

from __future__ import annotations

import time
from pathlib import Path

import msgspec
import pytest
from mcap.reader import make_reader

from common.recording import RecordingError, RecordingWriter, read_recording, summarize
from common.recording import schema as s
from common.recording.store import RecordingStore
from common.recording.writer import frame_record, pose_record, sample_record
from common.sim2d import maps
from common.world import packing

REPO = Path(__file__).resolve().parents[3]


def _info(agent: str = "k1", rid: str = "k1-1-abc", user: str = "alice") -> s.RunInfo:
    now = time.time()
    return s.RunInfo(
        ctx="arena",
        world="w1",
        agent=agent,
        user=user,
        request_id=rid,
        mode="deploy",
        filename="ctl.py",
        start=now,
        planned_end=now + 5,
    )


def _record(
    path: Path, *, seconds: float = 2.0, finish: bool = True, user: str = "alice"
) -> RecordingWriter:
    world = maps.load_map(REPO / "maps" / "empty.json", name="w1", seed=1)
    snap = packing.snapshot(world)
    agent = snap.agents[0].id
    writer = RecordingWriter(path, _info(agent, user=user))
    writer.write(s.SNAPSHOT, snap)
    slot = world.agent_slot(agent)
    t0 = time.time()
    for i in range(int(seconds / world.tick_s)):
        world.set_speeds(slot, 10, 10)  # straight ahead, ~80 mm/s
        world.step()
        t = t0 + i * world.tick_s
        rec = frame_record(packing.frame(world), snap.rows, len(snap.agents))
        writer.write(s.FRAME, rec, t)
        j = rec.rows.index(agent)
        writer.write(s.pose_topic(agent), pose_record(rec.x[j], rec.y[j], rec.heading[j], t), t)
        writer.write(s.sensors_topic(agent), sample_record(packing.sample(world, slot)), t)
        writer.write(
            s.commands_topic(agent),
            s.CommandRecord(agent=agent, sender="runner-svc", auth="signed", speeds=(10, 10)),
            t,
        )
    lines = [
        "hello",
        "Traceback (most recent call last):",
        '  File "/srv/wart/child.py", line 70, in run',
        '  File "/tmp/ctl.py", line 12, in do_work',
        "ZeroDivisionError: division by zero",
    ]
    for line in lines:
        writer.write(s.OUTPUT, s.LogLine(s.stamp(t0), 2, line, agent, "ctl.py", 0))
    writer.write(s.EVENTS, s.EventRecord(kind="running", request_id="k1-1-abc", agent=agent))
    writer.write(s.CHAT, s.ChatRecord(seq=1, sender="bob", text="go"))
    if finish:
        writer.finish(s.RunEnd(status="finished", reason="the controller raised", at=time.time()))
    return writer


def test_a_recording_reads_back_with_every_channel_and_its_schema(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path)
    # the plain mcap library reads it: JSON channels with jsonschema schemas
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
        encodings = {summary.schemas[c.schema_id].encoding for c in summary.channels.values()}
        names = {summary.schemas[c.schema_id].name for c in summary.channels.values()}
    assert {s.RUN, s.END, s.FRAME, s.SNAPSHOT, s.OUTPUT, s.EVENTS, s.CHAT} <= topics
    assert encodings == {"jsonschema"}
    assert {"foxglove.PoseInFrame", "foxglove.Log"} <= names
    rec = read_recording(path)
    assert rec.info is not None and rec.info.request_id == "k1-1-abc"
    assert rec.end is not None and rec.end.status == "finished"
    assert rec.frames and rec.samples and rec.commands and rec.poses and rec.chat and rec.events
    assert rec.truncated == ""


def test_the_summary_has_distance_time_moving_and_errors(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path)
    summary = summarize(read_recording(path))
    assert 100 < summary.distance_mm < 250, summary  # ~80 mm/s for 2 s
    assert summary.moving_s > 1.0
    assert summary.status == "finished"
    assert [(e.kind, e.line) for e in summary.errors] == [("ZeroDivisionError", 12)]
    # Its durations are said in the world's own time: simulated here, wall-clock on robots.
    from common.recording.report import describe

    assert summary.world_kind == "sim"
    assert any(line.endswith("s of simulated time") for line in describe(summary))
    real = msgspec.structs.replace(summary, world_kind="real")
    assert any(line.endswith("s of real time") for line in describe(real))
    # Real robots have no contact sensor: the count says it was estimated, or not measured.
    assert any(line.startswith("collisions:  0 (") for line in describe(summary))
    said = [line for line in describe(real) if line.startswith("collisions:")]
    assert said and said[0].endswith("estimated from the tracked poses (not measured)")
    unseen = msgspec.structs.replace(real, frames=0)
    said = [line for line in describe(unseen) if line.startswith("collisions:")]
    assert said == ["collisions:  not measured (real robots, and no tracked poses recorded)"]


def test_a_truncated_recording_is_salvaged_and_garbage_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path, seconds=6.0)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 3])
    rec = read_recording(cut)
    assert rec.truncated and rec.frames
    assert summarize(rec).status == "unknown"
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(RecordingError, match="not an MCAP recording"):
        read_recording(junk)
    head = tmp_path / "head.mcap"
    head.write_bytes(data[:40])
    with pytest.raises(RecordingError):
        read_recording(head)
    with pytest.raises(RecordingError, match="cannot open"):
        read_recording(tmp_path / "missing.mcap")


def test_a_deploy_runs_file_is_attached_and_read_back(tmp_path: Path) -> None:
    import hashlib

    source = b"from common.controller import Controller\n"
    info = msgspec.structs.replace(_info(), source_sha256=hashlib.sha256(source).hexdigest())
    writer = RecordingWriter(tmp_path / "run.mcap", info)
    writer.attach_source("ctl.py", source, info.start)
    writer.finish(s.RunEnd(status="finished", reason="", at=info.start + 1))
    rec = read_recording(tmp_path / "run.mcap")
    assert rec.source == source and rec.info == info
    with (tmp_path / "run.mcap").open("rb") as f:  # any MCAP tool lists it
        names = [a.name for a in make_reader(f).iter_attachments()]
    assert names == ["ctl.py"]


def test_retention_removes_the_oldest_of_that_user_only(tmp_path: Path) -> None:
    store = RecordingStore(tmp_path / "rec", keep=2)
    made = []
    for i in range(3):
        path = store.path_for("alice", f"k1-{i}-aaa")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x")
        made.append(path)
        t = 1000.0 + i
        import os

        os.utime(path, (t, t))
    bob = store.path_for("bob", "k2-9-bbb")
    bob.parent.mkdir(parents=True, exist_ok=True)
    bob.write_bytes(b"y")
    assert store.prune("alice") == [made[0]]
    assert [p.name for p in store.files("alice")] == [made[1].name, made[2].name]
    assert store.files("bob") == [bob]
    with pytest.raises(ValueError):
        store.path_for("alice", "../bob/k2")
