"""Read a recording back typed: every channel's records with their times.

Files are read sequentially (mcap's StreamReader with CRCs checked), so a
file cut short by a crash still gives what it holds (``truncated`` says so);
anything that is not a readable MCAP recording is one :class:`RecordingError`
with the reason, never a traceback.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

import msgspec
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Header, Message, Schema
from mcap.stream_reader import StreamReader

from common.messages import WorldSnapshot
from common.recording import schema as s

T = TypeVar("T")


class RecordingError(ValueError):
    """A file that is not a readable recording (missing, not MCAP, corrupt, foreign)."""


@dataclass(frozen=True)
class Stamped(Generic[T]):
    """A record and its log time (wall-clock seconds)."""

    t: float
    record: T


@dataclass
class Recording:
    path: Path
    info: s.RunInfo | None = None
    end: s.RunEnd | None = None
    snapshots: list[Stamped[WorldSnapshot]] = field(default_factory=list)
    frames: list[Stamped[s.FrameRecord]] = field(default_factory=list)
    poses: list[Stamped[s.PoseInFrame]] = field(default_factory=list)
    samples: list[Stamped[s.SampleRecord]] = field(default_factory=list)
    commands: list[Stamped[s.CommandRecord]] = field(default_factory=list)
    output: list[Stamped[s.LogLine]] = field(default_factory=list)
    events: list[Stamped[s.EventRecord]] = field(default_factory=list)
    chat: list[Stamped[s.ChatRecord]] = field(default_factory=list)
    tracked: list[Stamped[s.TrackedRecord]] = field(default_factory=list)
    tracked_poses: list[Stamped[s.PoseInFrame]] = field(default_factory=list)  # the run's robot
    images: list[Stamped[s.CompressedImage]] = field(default_factory=list)
    channels: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages
    source: bytes | None = None  # a deploy run's controller file (its attachment)
    truncated: str = ""  # why reading stopped early ("" when the file is whole)
    skipped: int = 0  # messages of unknown topics or that did not decode

    @property
    def snapshot(self) -> WorldSnapshot | None:
        return self.snapshots[0].record if self.snapshots else None


_SLOTS = {
    s.RunInfo: "info",
    s.RunEnd: "end",
    WorldSnapshot: "snapshots",
    s.FrameRecord: "frames",
    s.PoseInFrame: "poses",
    s.SampleRecord: "samples",
    s.CommandRecord: "commands",
    s.LogLine: "output",
    s.EventRecord: "events",
    s.ChatRecord: "chat",
    s.TrackedRecord: "tracked",
    s.CompressedImage: "images",
}


def read_recording(path: str | Path) -> Recording:
    """Every record of ``path``; RecordingError when it is not a readable recording."""
    path = Path(path)
    try:
        stream = path.open("rb")
    except OSError as exc:
        raise RecordingError(f"cannot open {path}: {exc.strerror or exc}") from None
    recording = Recording(path=path)
    with stream:
        reader = StreamReader(stream, validate_crcs=True, record_size_limit=256 * 2**20)
        decoders: dict[int, Any] = {}
        schemas: dict[int, Schema] = {}
        header_seen = False
        try:
            for record in reader.records:
                if isinstance(record, Header):
                    header_seen = True
                    if record.profile != s.PROFILE:
                        raise RecordingError(
                            f"{path} is an MCAP file but not a wart recording "
                            f"(profile {record.profile!r})"
                        )
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    cls = s.record_type(record.topic)
                    schema = schemas.get(record.schema_id)
                    recording.channels[record.topic] = schema.name if schema else ""
                    recording.counts.setdefault(record.topic, 0)
                    if cls is not None and record.message_encoding == s.JSON:
                        decoders[record.id] = (record.topic, cls, msgspec.json.Decoder(cls))
                elif isinstance(record, Message):
                    _add(recording, decoders.get(record.channel_id), record)
                elif isinstance(record, Attachment) and record.media_type == s.SOURCE_MEDIA_TYPE:
                    recording.source = bytes(record.data)
        except RecordingError:
            raise
        except (McapError, ValueError, OSError, EOFError, KeyError) as exc:
            # ValueError covers CRC mismatches and undecodable chunk data.
            if not header_seen:
                raise RecordingError(f"{path} is not an MCAP recording: {_why(exc)}") from None
            recording.truncated = f"the file is cut short or damaged: {_why(exc)}"
        except Exception as exc:  # zstd/lz4 raise their own types on garbage
            if not header_seen:
                raise RecordingError(f"{path} is not an MCAP recording: {_why(exc)}") from None
            recording.truncated = f"the file is damaged: {_why(exc)}"
    if recording.info is None:
        raise RecordingError(f"{path} holds no run record: {recording.truncated or 'not a run'}")
    return recording


def _why(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) < 200 else text[:200] + "..."


def _add(recording: Recording, decoder: Any, message: Message) -> None:
    if decoder is None:
        recording.skipped += 1
        return
    topic, cls, dec = decoder
    try:
        record = dec.decode(message.data)
    except (msgspec.ValidationError, msgspec.DecodeError):
        recording.skipped += 1
        return
    recording.counts[topic] = recording.counts.get(topic, 0) + 1
    slot = "tracked_poses" if topic.endswith("/tracked") else _SLOTS[cls]
    stamped = Stamped(message.log_time / 1e9, record)
    if slot in ("info", "end"):
        setattr(recording, slot, record)
    else:
        getattr(recording, slot).append(stamped)
