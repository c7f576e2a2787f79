"""Write one recording: an MCAP file of JSON channels with their schemas (the mcap library).

Not thread-safe by itself: one thread writes (the context's recorder thread).
The file is written as ``<name>.part`` and renamed when finished, so a file
without the suffix is always complete; chunks are small so a crash loses
seconds, not the run (the reader salvages a truncated file).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import IO, Any

import msgspec
from mcap.writer import CompressionType, Writer

from common.messages import AgentStates, SensorSample, WorldFrame, WorldSnapshot
from common.recording import schema as s

CHUNK_BYTES = 128 * 1024  # a crash loses at most this much (compressed chunks are smaller)
PART = ".part"

_encode = msgspec.json.Encoder().encode


def frame_record(frame: WorldFrame, rows: list[str], agents: int) -> s.FrameRecord:
    """The JSON record of a wire frame (rows named from the world's snapshot)."""
    poses = frame.poses.to_numpy()
    n = min(len(rows), poses.shape[0])
    states = AgentStates.unpack(frame.agent_state, agents)
    return s.FrameRecord(
        tick=frame.tick,
        sim_time=frame.sim_time,
        layout=frame.layout,
        agents=min(agents, n),
        rows=rows[:n],
        x=[round(float(v), 2) for v in poses[:n, 0]],  # 0.01 mm: what the float32 carries
        y=[round(float(v), 2) for v in poses[:n, 1]],
        heading=[round(float(v), 4) for v in poses[:n, 2]],
        fingers=[] if states is None else [int(v) for v in states.fingers],
    )


def sample_record(sample: SensorSample) -> s.SampleRecord:
    gripper = None if sample.gripper is None else msgspec.to_builtins(sample.gripper)
    return s.SampleRecord(
        agent=sample.agent,
        tick=sample.tick,
        sim_time=sample.sim_time,
        proximity=list(sample.proximity),
        ambient=list(sample.ambient),
        counters=sample.counters,
        speeds=sample.speeds,
        leds=list(sample.leds),
        gripper=gripper,
    )


def pose_record(x_mm: float, y_mm: float, heading: float, t: float) -> s.PoseInFrame:
    return s.PoseInFrame(
        timestamp=s.stamp(t),
        frame_id="arena",
        pose=s.Pose(
            position=s.Vector3(x_mm / 1000.0, y_mm / 1000.0, 0.0),
            orientation=s.Quaternion(0.0, 0.0, math.sin(heading / 2), math.cos(heading / 2)),
        ),
    )


class RecordingWriter:
    """One run's MCAP file; every channel is declared at the start (present even if empty)."""

    def __init__(self, path: Path, info: s.RunInfo) -> None:
        self.path = path
        self.part = path.with_name(path.name + PART)
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file: IO[bytes] = open(self.part, "wb")  # noqa: SIM115 - closed in finish()
        os.chmod(self.part, 0o600)  # a student's run is theirs (and the managers')
        self._mcap = Writer(self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
        self._mcap.start(profile=s.PROFILE, library="wart")
        self._schemas: dict[type, int] = {}
        self._channels: dict[str, int] = {}
        self.messages = 0
        self.closed = False
        self.agent = info.agent
        for topic in (s.RUN, s.SNAPSHOT, s.FRAME, s.EVENTS, s.CHAT, s.OUTPUT, s.END):
            self._channel(topic)
        for topic in (
            s.pose_topic(info.agent),
            s.sensors_topic(info.agent),
            s.commands_topic(info.agent),
        ):
            self._channel(topic)
        self.write(s.RUN, info, info.start)
        self._mcap.add_metadata(
            "wart.run", {k: str(v) for k, v in msgspec.structs.asdict(info).items()}
        )

    def _channel(self, topic: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            cls = s.record_type(topic)
            assert cls is not None, topic
            schema = self._schemas.get(cls)
            if schema is None:
                schema = self._mcap.register_schema(
                    s.schema_name(cls), "jsonschema", s.json_schema(cls)
                )
                self._schemas[cls] = schema
            channel = self._mcap.register_channel(topic, s.JSON, schema)
            self._channels[topic] = channel
        return channel

    def attach_source(self, name: str, source: bytes, t: float) -> None:
        """The run's controller file, as an MCAP attachment (a tool lists and saves it)."""
        ns = int(t * 1e9)
        self._mcap.add_attachment(ns, ns, name, s.SOURCE_MEDIA_TYPE, source)

    def write(self, topic: str, record: Any, t: float | None = None) -> None:
        """Append ``record`` on ``topic`` at wall-clock time ``t`` (now if None)."""
        ns = int((time.time() if t is None else t) * 1e9)
        if isinstance(record, WorldSnapshot):
            record = msgspec.structs.replace(record, identity=None)  # a token is no one's business
        self._mcap.add_message(self._channel(topic), ns, _encode(record), ns)
        self.messages += 1

    def finish(self, end: s.RunEnd) -> Path:
        """Write the end, the summary section, close and rename: the finished file's path."""
        if self.closed:
            return self.path
        self.write(s.END, end, end.at)
        self._mcap.add_metadata("wart.end", {"status": end.status, "reason": end.reason})
        self._mcap.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        self.closed = True
        os.replace(self.part, self.path)
        return self.path

    def abandon(self) -> None:
        """Close without the end (the process stopping hard): the .part stays, salvageable."""
        if not self.closed:
            self.closed = True
            try:
                self._mcap.flush()
            finally:
                self._file.close()
