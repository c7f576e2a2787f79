"""Every slot of an agent context, recorded: the robot, what it sensed, was commanded, printed.

The recorder subscribes like any other client (the engine's tick never waits
for it): ``world/<w>/agent/*/cmd`` and ``world/<w>/cmds`` (the commands,
checked as the world checks them: the lease holder's, MACed with the run's
lease key or signed by the holder's session, sent within the slot; a refused
command is counted, not recorded). While a slot is recorded (its trail
included) also ``world/<w>/frame`` (the poses of everything),
``world/<w>/samples`` (the sensor samples of leased robots) and a real arena's
camera videos: a world builds no frame, and a camera encodes no video, that
no one reads. The context hands it the output lines, its events and the chat.

Zenoh callbacks only look whether a run of that robot is being recorded and
queue the payload; one thread decodes, checks and writes (common/recording/),
so a slow disk delays only that thread. When the queue is full the newest
items are dropped and counted (said in the run's end event).

A run's file stays open :data:`TRAIL_S` after its slot ends: the robot
stopping and the controller's last lines (a traceback) trail the end. Then
its summary is written beside it and the user's oldest recordings beyond the
limit are removed.
"""

from __future__ import annotations

import hashlib
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from common import keys
from common.ask import ask
from common.auth import Verifier
from common.lab_errors import LabError
from common.messages import (
    AgentContextState,
    AgentEvent,
    ChatLine,
    MemberStatus,
    MessageError,
    SampleBundle,
    SensorSample,
    WorldFrame,
    WorldSnapshot,
    decode,
)
from common.recording import read_recording, summarize
from common.recording import schema as s
from common.recording.reader import RecordingError
from common.recording.store import RecordingStore
from common.recording.writer import RecordingWriter, frame_record, pose_record, sample_record
from common.worker import Worker
from services.context.agent_queue import RunningJob
from services.context.camera_tap import CameraTap
from services.context.command_tap import CommandTap
from services.context.recorder_feeds import RecorderFeeds

TRAIL_S = 1.5  # how long a file stays open after its slot: the stop and the last lines
QUEUE_MAX = 20_000  # items waiting for the writer thread (~7 min of one robot at 50 Hz)
SNAPSHOT_RETRY_S = 2.0


@dataclass
class _Run:
    run: RunningJob
    driver: str  # the account that drives (the runner's for an upload)
    writer: RecordingWriter
    closing_at: float | None = None
    end: s.RunEnd | None = None
    refused: int = 0
    last_queue: str = ""
    extra: dict[str, int] = field(default_factory=dict)


class SlotRecorder:
    """The recordings of one context's runs (disabled, doing nothing, with ``store`` None)."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        ctx: str,
        world: str,
        store: RecordingStore | None,
        registry_key: bytes,
        log: logging.Logger,
    ) -> None:
        self.session, self.realm, self.ctx, self.world = session, realm, ctx, world
        self.store = store
        self.log = log
        # Its own verifier: opening the holder's command envelopes must not move the
        # replay windows the context's requests and outputs are checked against.
        self.verifier = Verifier(registry_key, realm)
        self._queue: queue.Queue[tuple[Any, ...]] = queue.Queue(QUEUE_MAX)
        self._runs: dict[str, _Run] = {}  # request id -> run (writer thread only)
        self._agents: dict[str, str] = {}  # agent -> request id being recorded (any thread)
        self._lock = threading.Lock()
        self._worker = Worker(self._work, "recorder")
        self.feeds = RecorderFeeds(session, log)
        self._snapshot: WorldSnapshot | None = None
        self._snapshot_tried = 0.0
        self.dropped = 0
        self.recorded = 0  # finished recordings
        self.camera = CameraTap(self)  # a real arena's video and tracked poses
        self.commands = CommandTap(self)  # the commands, checked as the world checks them

    @property
    def enabled(self) -> bool:
        return self.store is not None

    # -- lifecycle

    def start(self) -> None:
        if self.store is None:
            return
        for path in self.store.salvage_parts():
            self.log.warning("recording %s was cut short by a crash: kept as it is", path.name)
        w, r = self.world, self.realm
        self.feeds.hear(
            [
                (keys.agent_cmd_all(r, w), self._on_cmd),
                (keys.world_commands(r, w), self._on_bundle),
                *self.camera.subscriptions(),
            ]
        )
        self._worker.start()

    def close(self, timeout: float) -> None:
        """Finish every open recording now (no trail) and stop the thread."""
        self._worker.stopping.set()  # first: no feed is heard again while it closes
        self.feeds.close()
        self._worker.stop(timeout)

    # -- what the context tells it (any thread)

    def run_started(self, run: RunningJob, driver: str) -> None:
        if self.store is None:
            return
        with self._lock:
            self._agents[run.job.agent] = run.job.request_id
        self._watch()
        self._put(("start", run, driver))

    def run_ended(self, request_id: str, status: str, reason: str) -> None:
        if self.store is not None:
            self._put(("end", request_id, status, reason, time.time()))

    def output(self, request_id: str, agent: str, lines: list[str]) -> None:
        if self.store is not None:
            self._put(("output", request_id, agent, lines, time.time()))

    def event(self, event: AgentEvent) -> None:
        if self.store is None:
            return
        if event.request is not None or event.state is not None:
            self._put(("event", event, time.time()))

    def world_snapshot(self, snap: WorldSnapshot) -> None:
        """The world's snapshot as the context's slot engine fetched it.

        The recorder then names a run's rows without asking the world itself at
        the run's start: on a loaded machine that query could miss a short slot
        entirely and leave a recording no one can compare (seen in a busy run).
        """
        if self.store is not None:
            self._put(("snapshot", snap))

    def chat(self, line: ChatLine | None, status: MemberStatus | None) -> None:
        if self.store is not None and (line is not None or status is not None):
            self._put(("chat", line, status, time.time()))

    def _watch(self) -> None:
        """The world's frames and samples and the cameras' videos, heard while a slot is
        recorded (after each change to the runs): a world builds no frame, a camera
        encodes no video, that no one reads."""
        self.feeds.hear_while(
            lambda: self.any_recorded() and not self._worker.stopping.is_set(), self._while
        )

    def _while(self) -> list[tuple[str, Callable[[zenoh.Sample], None]]]:
        w, r = self.world, self.realm
        return [
            (keys.world_frame(r, w), self._on_frame),
            (keys.world_samples(r, w), self._on_samples),
            *self.camera.while_recording(),
        ]

    # -- Zenoh callbacks: a look and a queue put, nothing more

    def is_recording(self, agent: str) -> bool:
        """Whether a slot of ``agent`` is being recorded (its trail included); any thread."""
        with self._lock:
            return agent in self._agents

    def any_recorded(self) -> bool:
        """Whether any slot is being recorded; any thread."""
        with self._lock:
            return bool(self._agents)

    def _put(self, item: tuple[Any, ...]) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _on_frame(self, sample: zenoh.Sample) -> None:
        if self.any_recorded():
            self._put(("frame", sample.payload.to_bytes(), time.time()))

    def _on_samples(self, sample: zenoh.Sample) -> None:
        if self.any_recorded():
            self._put(("samples", sample.payload.to_bytes(), time.time()))

    def _on_cmd(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        agent = keys.parse_agent_key(self.realm, self.world, key)
        if agent is not None and self.is_recording(agent):
            self._put(("cmd", key, agent, sample.payload.to_bytes(), time.time()))

    def _on_bundle(self, sample: zenoh.Sample) -> None:
        if self.any_recorded():
            self._put(("bundle", sample.payload.to_bytes(), time.time()))

    # -- the writer thread

    def _work(self) -> None:
        handlers: dict[str, Callable[..., None]] = {
            "start": self._start,
            "end": self._end,
            "output": self._output,
            "event": self._event,
            "chat": self._chat,
            "frame": self._frame,
            "samples": self._samples,
            "cmd": self.commands.command,
            "bundle": self.commands.bundle,
            "snapshot": self._note_snapshot,
            **self.camera.handlers(),
        }
        while not self._worker.stopping.is_set():
            try:
                item = self._queue.get(timeout=0.2)
            except queue.Empty:
                item = None
            try:
                if item is not None:
                    handlers[item[0]](*item[1:])
                self._close_due(time.time())
            except Exception:
                self.log.exception("error in the recorder (kept running)")
        # Stopping: what is queued still goes in, then every file is finished.
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            try:
                handlers[item[0]](*item[1:])
            except Exception:
                self.log.exception("error in the recorder while stopping")
        self._close_due(float("inf"))

    def _note_snapshot(self, snap: WorldSnapshot) -> None:
        if self._snapshot is not None and self._snapshot.layout == snap.layout:
            return
        self._snapshot = snap
        for rec in self._runs.values():
            rec.writer.write(s.SNAPSHOT, snap)

    def _world_snapshot(self, force: bool = False) -> WorldSnapshot | None:
        now = time.monotonic()
        if self._snapshot is not None and not force:
            return self._snapshot
        # At most one query per SNAPSHOT_RETRY_S, answered or not: a world that does not
        # answer would otherwise hold this thread 3 s for every frame.
        if now - self._snapshot_tried < SNAPSHOT_RETRY_S:
            return self._snapshot
        self._snapshot_tried = now
        key = keys.world_snapshot(self.realm, self.world)
        try:
            snap = ask(
                self.session, key, None, WorldSnapshot, what=f"world {self.world}", timeout=3.0
            )
        except LabError as exc:
            self.log.info("recorder: snapshot of %s: %s", self.world, exc)
            return self._snapshot
        self._note_snapshot(snap)
        return self._snapshot

    def _start(self, run: RunningJob, driver: str) -> None:
        assert self.store is not None
        job = run.job
        uploaded = job.mode == "deploy" and bool(job.source)
        info = s.RunInfo(
            ctx=self.ctx,
            world=self.world,
            agent=job.agent,
            user=job.user,
            request_id=job.request_id,
            mode=job.mode,
            filename=job.filename if job.mode == "deploy" else "",
            start=run.start,
            planned_end=run.end,
            source_sha256=hashlib.sha256(job.source).hexdigest() if uploaded else "",
        )
        try:
            writer = RecordingWriter(self.store.path_for(job.user, job.request_id), info)
        except OSError as exc:
            self.log.error("cannot record %s: %s", job.request_id, exc)
            with self._lock:
                self._agents.pop(job.agent, None)
            self._watch()
            return
        if uploaded:
            writer.attach_source(job.filename, job.source, run.start)
        rec = _Run(run=run, driver=driver, writer=writer)
        self._runs[job.request_id] = rec
        snap = self._world_snapshot()
        if snap is not None:
            writer.write(s.SNAPSHOT, snap)
        writer.write(
            s.EVENTS,
            s.EventRecord(
                kind="started",
                request_id=job.request_id,
                agent=job.agent,
                user=job.user,
                detail=f"driven by {driver} ({job.mode})",
            ),
            run.start,
        )

    def _end(self, request_id: str, status: str, reason: str, at: float) -> None:
        rec = self._runs.get(request_id)
        if rec is None or rec.end is not None:
            return
        rec.end = s.RunEnd(status=status, reason=reason, at=at)
        rec.closing_at = time.time() + TRAIL_S

    def _close_due(self, now: float) -> None:
        for request_id, rec in list(self._runs.items()):
            if rec.closing_at is None and now != float("inf"):
                continue
            if rec.closing_at is not None and rec.closing_at > now:
                continue
            del self._runs[request_id]
            with self._lock:
                if self._agents.get(rec.run.job.agent) == request_id:
                    del self._agents[rec.run.job.agent]
            self._watch()
            self._finish(rec)

    def _finish(self, rec: _Run) -> None:
        assert self.store is not None
        end = rec.end or s.RunEnd(
            status="cancelled", reason="the agent context stopped", at=time.time()
        )
        if rec.refused or self.dropped:
            rec.writer.write(
                s.EVENTS,
                s.EventRecord(
                    kind="recorder",
                    request_id=rec.run.job.request_id,
                    detail=f"{rec.refused} commands refused (not the holder's, or outside "
                    f"the slot); {self.dropped} items dropped by a full recorder queue",
                ),
            )
        try:
            path = rec.writer.finish(end)
        except OSError as exc:
            self.log.error("recording %s could not be finished: %s", rec.run.job.request_id, exc)
            return
        self.recorded += 1
        user = rec.run.job.user
        try:
            summary = summarize(read_recording(path))
            self.store.save_summary(path, summary)
        except (RecordingError, OSError) as exc:
            self.log.warning("no summary for %s: %s", path.name, exc)
        self.store.prune(user)
        self.log.info("recorded %s (%d messages) for %s", path.name, rec.writer.messages, user)

    def active_run(self, agent: str) -> _Run | None:
        """The run of ``agent`` being recorded, if any (the writer thread's, with its file)."""
        with self._lock:
            request_id = self._agents.get(agent)
        return self._runs.get(request_id) if request_id else None

    def _frame(self, payload: bytes, t: float) -> None:
        if not self._runs:
            return
        try:
            frame = decode(payload, WorldFrame)
        except MessageError:
            return
        snap = self._snapshot
        if snap is None or snap.layout != frame.layout:
            snap = self._world_snapshot(force=True)
            if snap is None or snap.layout != frame.layout:
                return  # rows unknown: a frame we cannot name is not recorded
        record = frame_record(frame, snap.rows, len(snap.agents))
        for rec in self._runs.values():
            rec.writer.write(s.FRAME, record, t)
            agent = rec.run.job.agent
            if agent in record.rows:
                i = record.rows.index(agent)
                pose = pose_record(record.x[i], record.y[i], record.heading[i], t)
                rec.writer.write(s.pose_topic(agent), pose, t)

    def _samples(self, payload: bytes, t: float) -> None:
        try:
            bundle = decode(payload, SampleBundle)
        except MessageError:
            return
        for agent, raw in zip(bundle.agents, bundle.samples, strict=False):
            rec = self.active_run(agent)
            if rec is None:
                continue
            try:
                sample = decode(bytes(raw), SensorSample)
            except MessageError:
                continue
            rec.writer.write(s.sensors_topic(agent), sample_record(sample), t)

    def _output(self, request_id: str, agent: str, lines: list[str], t: float) -> None:
        rec = self._runs.get(request_id)
        if rec is None:
            return
        in_trace = False
        for line in lines:
            in_trace = in_trace or line.startswith("Traceback")
            level = 4 if in_trace else 2
            rec.writer.write(
                s.OUTPUT,
                s.LogLine(s.stamp(t), level, line, agent, rec.run.job.filename, 0),
                t,
            )

    def _event(self, event: AgentEvent, t: float) -> None:
        if event.request is not None:
            status = event.request
            for rec in self._runs.values():
                mine = status.request_id == rec.run.job.request_id
                if mine or status.agent == rec.run.job.agent:
                    rec.writer.write(
                        s.EVENTS,
                        s.EventRecord(
                            kind=status.takeover or status.status,  # or taken, handed_back
                            request_id=status.request_id,
                            agent=status.agent,
                            user=status.user,
                            reason=status.reason,
                        ),
                        t,
                    )
        if event.state is not None:
            self._queue_state(event.state, t)

    def _queue_state(self, state: AgentContextState, t: float) -> None:
        for rec in self._runs.values():
            for line in state.agents:
                if line.agent != rec.run.job.agent:
                    continue
                detail = "; ".join(
                    f"{e.position}:{e.user}:{e.request_id}" for e in line.entries
                ) + ("" if line.enabled else " (disabled)")
                if detail != rec.last_queue:
                    rec.last_queue = detail
                    rec.writer.write(
                        s.EVENTS, s.EventRecord(kind="queue", agent=line.agent, detail=detail), t
                    )

    def _chat(self, line: ChatLine | None, status: MemberStatus | None, t: float) -> None:
        for rec in self._runs.values():
            if line is not None:
                rec.writer.write(
                    s.CHAT, s.ChatRecord(seq=line.seq, sender=line.sender, text=line.text), t
                )
            if status is not None:
                rec.writer.write(
                    s.EVENTS,
                    s.EventRecord(
                        kind=status.status,
                        user=status.user,
                        reason=status.reason,
                        detail=f"by {status.by}" if status.by else "",
                    ),
                    t,
                )
