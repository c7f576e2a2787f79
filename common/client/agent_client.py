"""A user's side of an agent context: queue, wait, drive or upload, see the output.

Used by ``wart control`` / ``wart deploy``, by the web viewer and by tests::

    with LabClient(zsession, realm, registry_key) as client:
        client.login("alice", password)
        agents = AgentClient(client, "arena").join()
        queued = agents.queue("k1", "deploy", source=Path("avoid.py").read_bytes())
        status = agents.wait_status(queued.request_id, {"finished", "cancelled", "refused"})

For ``remote`` mode, :meth:`AgentClient.drive` runs a controller on this
machine during the slot (it queues, waits for the lease, drives over Zenoh,
stops at the slot's end or when the context ends the request).
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from common import keys, qos
from common.client.lab_client import LabClient
from common.client.rooms import RoomHandle
from common.controller import Controller, ControllerLoop, Khepera
from common.lab_errors import LabError, NotFound, NotLoggedIn
from common.messages import (
    ENDED,
    AgentContextState,
    AgentEvent,
    CancelControl,
    ContextSettings,
    ControllerOutput,
    ControlQueued,
    ControlRequest,
    DryRunReport,
    DryRunRequest,
    EmergencyStop,
    FileContent,
    FileList,
    FileListRequest,
    HandBack,
    OkReply,
    OutputLines,
    OutputSoFar,
    OutputSoFarRequest,
    QueueStateRequest,
    ReadFile,
    RecordingChunk,
    RecordingGet,
    RecordingList,
    RecordingListRequest,
    RequestStatus,
    RequestStatusQuery,
    RequestStatusReply,
    RoomEvent,
    RunMode,
    SaveFile,
    StopControl,
    TakenOver,
    TakeOver,
)
from common.recording.reader import Recording
from common.world.remote_robot import ZenohRobotLink

log = logging.getLogger("wart.agent_client")

FINAL = ENDED  # a request's last statuses
# A dry run's answer: the runner's wall-clock limit (DRY_RUN_WALL_S in
# services/runner/dryrun.py) plus the hops and the sandbox's start.
DRY_RUN_WAIT_S = 30.0


@dataclass
class DriveResult:
    request_id: str
    status: str  # finished, cancelled, refused, interrupted
    reason: str
    iterations: int = 0
    error: str = ""  # the controller's traceback, if it raised


@dataclass
class AgentClient:
    """One agent context as a user sees it, over a logged-in LabClient."""

    client: LabClient
    ctx: str
    on_output: Callable[[OutputLines], None] = lambda _o: None
    on_state: Callable[[AgentContextState], None] = lambda _s: None
    on_status: Callable[[RequestStatus], None] = lambda _s: None
    on_room: Callable[[RoomEvent], None] = lambda _e: None
    latest_state: AgentContextState | None = None
    room: RoomHandle | None = None  # what the join said (title, owner, members, history)
    # When the context's events last came (monotonic s): a long silence may be a missed event.
    last_heard: float = field(default_factory=time.monotonic)
    _statuses: dict[str, list[RequestStatus]] = field(default_factory=dict)
    _cond: threading.Condition = field(default_factory=threading.Condition)

    def join(self, history: int = 0) -> AgentClient:
        keys.check_ident("context", self.ctx)
        self.room = self.client.join(self.ctx, self.on_room, history, on_agent_event=self._on_event)
        self.latest_state = self.state()
        return self

    def leave(self) -> None:
        self.client.leave(self.ctx)

    # -- events (Zenoh thread: short)

    def _on_event(self, event: AgentEvent) -> None:
        self.last_heard = time.monotonic()
        if event.state is not None:
            with self._cond:
                if self.latest_state is None or event.state.at >= self.latest_state.at:
                    self.latest_state = event.state
            self.on_state(event.state)
        if event.request is not None:
            with self._cond:
                self._statuses.setdefault(event.request.request_id, []).append(event.request)
                self._cond.notify_all()
            self.on_status(event.request)
        if event.output is not None:
            self.on_output(event.output)

    # -- requests

    def state(self) -> AgentContextState:
        state = self.client.request(
            self.ctx, QueueStateRequest(), AgentContextState, f"queues of {self.ctx}"
        )
        with self._cond:
            if self.latest_state is None or state.at >= self.latest_state.at:
                self.latest_state = state
        return state

    def output_so_far(self, request_id: str) -> OutputSoFar:
        """A run's last output lines as the context kept them (NotFound: no such request)."""
        return self.client.request(
            self.ctx,
            OutputSoFarRequest(request_id=request_id),
            OutputSoFar,
            f"output of request {request_id}",
        )

    def queue(
        self, agent: str, mode: RunMode, *, source: bytes = b"", filename: str = "controller.py"
    ) -> ControlQueued:
        request = ControlRequest(agent=agent, mode=mode, source=source, filename=filename)
        return self.client.request(self.ctx, request, ControlQueued, f"queue on {agent}")

    def promote(self, recording: Recording, agent: str | None = None) -> ControlQueued:
        """Queue the file of a recorded deploy run (say in simulation) on this context's robot
        ``agent`` (default: the recorded run's agent), typically the real arena: "promote to
        real". LabError when the recording holds no file or it does not match its hash."""
        info = recording.info
        if info is None or info.mode != "deploy" or recording.source is None:
            raise LabError(
                f"{recording.path} holds no controller file to promote: only an uploaded "
                "(deploy) run's file is recorded; a remote run's code stayed on its machine"
            )
        if hashlib.sha256(recording.source).hexdigest() != info.source_sha256:
            raise LabError(f"{recording.path}: the recorded file does not match its hash")
        return self.queue(
            agent or info.agent, "deploy", source=recording.source, filename=info.filename
        )

    def cancel(self, request_id: str) -> str:
        reply = self.client.request(
            self.ctx, CancelControl(request_id=request_id), OkReply, f"cancel {request_id}"
        )
        return reply.detail

    def stop_agent(self, agent: str, reason: str = "") -> str:
        reply = self.client.request(
            self.ctx, StopControl(agent=agent, reason=reason), OkReply, f"stop {agent}"
        )
        return reply.detail

    def emergency_stop(self, reason: str = "", *, release: bool = False) -> str:
        """Stop every robot of the arena and hold it (the context's managers only);
        ``release=True`` lets slots start again. Returns what the context said."""
        message = EmergencyStop(engaged=not release, reason=reason)
        what = "release the emergency stop" if release else "emergency stop"
        return self.client.request(self.ctx, message, OkReply, what).detail

    def take_over(self, agent: str, reason: str = "") -> TakenOver:
        """Take over ``agent`` while a student's controller runs on it (the context's
        managers): the controller is paused, this session drives (:meth:`robot_link`)
        until :meth:`hand_back` or the slot's end. LabError with the context's reason
        if refused (not a manager, nothing running, taken by someone else)."""
        message = TakeOver(agent=agent, reason=reason)
        return self.client.request(self.ctx, message, TakenOver, f"take over {agent}")

    def hand_back(self, agent: str) -> str:
        """Give a taken-over ``agent`` back to its student's controller; what the context said."""
        message = HandBack(agent=agent)
        return self.client.request(self.ctx, message, OkReply, f"hand back {agent}").detail

    def robot_link(self, world: str, agent: str) -> ZenohRobotLink:
        """A link that drives ``agent`` with this session, while it holds the agent's lease
        (its own request running, or a take-over); close it when done."""
        return ZenohRobotLink(
            self.client.z,
            self.client.realm,
            world,
            agent,
            lambda: self.client.session,  # type: ignore[arg-type,return-value]
            verifier=self.client.verifier,  # accepts a MAC lease: commands cost µs to check
        )

    def drive_taken(
        self, taken: TakenOver, controller: Controller, stop: threading.Event | None = None
    ) -> int:
        """Run ``controller`` on this machine on a robot this session took over, until the
        slot's end, ``stop``, or the context says the take-over ended (handed back by
        another manager, the run ended). Does not hand back. Returns its iterations."""
        stop = stop or threading.Event()
        # The take-over is in the context's state from its reply on: read it now, or the
        # watch below could see an older state (its event not come yet) and end at once.
        self.state()
        link = self.robot_link(taken.world, taken.agent)
        loop = ControllerLoop(controller, Khepera(link))
        me = self.client.user

        def watch() -> None:
            while not loop.stop.is_set():
                if stop.wait(0.2) or not self.is_taken_by(taken.agent, me):
                    loop.stop.set()

        watcher = threading.Thread(target=watch, name="takeover-watch", daemon=True)
        watcher.start()
        try:
            loop.run(until=time.monotonic() + max(0.0, taken.end - time.time()))
        finally:
            loop.stop.set()
            link.close(stop=True)
        return loop.iterations

    def is_taken_by(self, agent: str, user: str | None) -> bool:
        """Whether the newest queue state says ``user`` has taken ``agent`` over."""
        state = self.latest_state
        for line in state.agents if state else []:
            if line.agent == agent:
                return any(e.position == 0 and e.taken_by == user for e in line.entries)
        return False

    def dry_run(
        self, agent: str, source: bytes, *, filename: str = "controller.py", seconds: float = 5.0
    ) -> DryRunReport:
        """A few simulated seconds of ``source`` in a private copy of the arena (needs
        ``deploy`` on the agent); nothing is queued. The report's ``verdict`` says
        "will run" or "will NOT run: ..."."""
        message = DryRunRequest(agent=agent, source=source, filename=filename, seconds=seconds)
        return self.client.request(
            self.ctx,
            message,
            DryRunReport,
            f"dry run on {agent}",
            key=keys.ctx_dryrun(self.client.realm, self.ctx),
            timeout=DRY_RUN_WAIT_S,
        )

    def settings(
        self,
        *,
        slot_seconds: float | None = None,
        enabled: bool | None = None,
        agent: str | None = None,
    ) -> str:
        message = ContextSettings(slot_seconds=slot_seconds, enabled=enabled, agent=agent)
        return self.client.request(self.ctx, message, OkReply, "change settings").detail

    def request_status(self, request_id: str) -> RequestStatusReply | None:
        """Where ``request_id`` stands, as the context says now; None if the context does
        not answer at all (stopped, restarting, out of reach), which says nothing about
        the request. For a caller that may have missed the request's last event: an
        ended status it learns this way is kept as if the event had come, so
        :meth:`wait_status` returns it. LabError if the context refuses (not yours).
        """
        try:
            reply = self.client.request(
                self.ctx,
                RequestStatusQuery(request_id=request_id),
                RequestStatusReply,
                f"status of request {request_id}",
                key=keys.ctx_status(self.client.realm, self.ctx),
            )
        except NotFound:  # the context never answers not_found here: nobody answered
            return None
        if reply.ended and reply.status is not None:
            with self._cond:
                seen = self._statuses.setdefault(request_id, [])
                if not any(s.status in FINAL for s in seen):
                    seen.append(reply.status)
                    self._cond.notify_all()
        return reply

    # -- recordings (every slot is recorded by the context: common/recording/)

    def recordings(self, user: str | None = None, *, all_users: bool = False) -> RecordingList:
        """Your recordings in this context; another user's (or all) with the manage right."""
        request = RecordingListRequest(user=user, all_users=all_users)
        return self.client.request(self.ctx, request, RecordingList, "list recordings")

    def download(
        self,
        name: str,
        dest: Path,
        *,
        summary: bool = False,
        progress: Callable[[int, int], None] = lambda _done, _total: None,
    ) -> Path:
        """Fetch recording ``name`` (or its summary) into ``dest`` in chunks; ``dest``.

        Written to ``dest.part`` first: an interrupted download leaves no file that
        looks complete.
        """
        part = dest.with_name(dest.name + ".part")
        offset, total = 0, None
        with part.open("wb") as out:
            while total is None or offset < total:
                chunk = self.client.request(
                    self.ctx,
                    RecordingGet(name=name, offset=offset, summary=summary),
                    RecordingChunk,
                    f"download {name}",
                )
                total = chunk.total
                if not chunk.data and offset < total:
                    raise LabError(f"{name} shrank while downloading: try again")
                out.write(chunk.data)
                offset += len(chunk.data)
                progress(offset, total)
        part.replace(dest)
        return dest

    # -- my files, kept by the context (the page's editor); always the caller's own

    def save_file(self, name: str, source: bytes) -> str:
        reply = self.client.request(
            self.ctx, SaveFile(name=name, source=source), OkReply, f"save {name}"
        )
        return reply.detail

    def list_files(self) -> FileList:
        return self.client.request(self.ctx, FileListRequest(), FileList, "list my files")

    def read_file(self, name: str) -> FileContent:
        return self.client.request(self.ctx, ReadFile(name=name), FileContent, f"read {name}")

    # -- waiting

    def statuses(self, request_id: str) -> list[RequestStatus]:
        with self._cond:
            return list(self._statuses.get(request_id, []))

    def wait_status(
        self,
        request_id: str,
        wanted: set[str] | frozenset[str],
        timeout: float | None = None,
        stop: threading.Event | None = None,
    ) -> RequestStatus | None:
        """The newest status of ``request_id`` among ``wanted`` (None on timeout or ``stop``)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while True:
                for status in reversed(self._statuses.get(request_id, [])):
                    if status.status in wanted:
                        return status
                if stop is not None and stop.is_set():
                    return None
                remaining = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)

    def statuses_of_user(self, user: str) -> list[str]:
        """Request ids of ``user`` in the newest queue state (running first)."""
        state = self.latest_state
        return [
            entry.request_id
            for line in (state.agents if state else [])
            for entry in line.entries
            if entry.user == user
        ]

    def position(self, request_id: str) -> tuple[int, float | None] | None:
        """(position, estimated start) of a request in the newest queue state; None if gone."""
        state = self.latest_state
        if state is None:
            return None
        for line in state.agents:
            for entry in line.entries:
                if entry.request_id == request_id:
                    return entry.position, entry.start_eta
        return None

    def position_of_user(self, user: str, agent: str) -> int | None:
        """The position of ``user``'s first request on ``agent`` (0 running); None if none."""
        state = self.latest_state
        for line in state.agents if state else []:
            if line.agent == agent:
                for entry in line.entries:
                    if entry.user == user:
                        return entry.position
        return None

    # -- remote mode: drive from this machine

    def drive(
        self,
        agent: str,
        controller: Controller,
        *,
        stop: threading.Event | None = None,
        on_wait: Callable[[int, float | None], None] = lambda _p, _e: None,
        on_start: Callable[[RequestStatus], None] = lambda _s: None,
    ) -> DriveResult:
        """Queue, wait for the slot, run ``controller`` on this machine for it, return why it ended.

        ``stop`` (e.g. set on Ctrl-C) cancels the request, waiting or running.
        """
        stop = stop or threading.Event()
        queued = self.queue(agent, "remote")
        rid = queued.request_id
        on_wait(queued.position, queued.start_eta)
        try:
            return self._drive_queued(rid, agent, controller, stop, on_wait, on_start)
        except BaseException:
            self.cancel_quietly(rid)
            raise

    def _drive_queued(
        self,
        rid: str,
        agent: str,
        controller: Controller,
        stop: threading.Event,
        on_wait: Callable[[int, float | None], None],
        on_start: Callable[[RequestStatus], None],
    ) -> DriveResult:
        shown: tuple[int, float | None] | None = None
        started: RequestStatus | None = None
        while started is None:
            status = self.wait_status(rid, FINAL | {"running"}, timeout=0.5, stop=stop)
            if stop.is_set():
                self.cancel_quietly(rid)
                return DriveResult(rid, "interrupted", "stopped before its slot")
            if status is not None and status.status != "running":
                return DriveResult(rid, status.status, status.reason)
            if status is not None:
                started = status
                break
            where = self.position(rid)
            if where is not None and where != shown and where[0] > 0:
                shown = where
                on_wait(*where)
        on_start(started)
        state = self.latest_state
        assert state is not None
        session = self.client.session
        if session is None:
            raise NotLoggedIn("logged out while waiting")
        end = started.end or time.time()
        link = ZenohRobotLink(
            self.client.z,
            self.client.realm,
            state.world,
            agent,
            lambda: self.client.session,  # type: ignore[arg-type,return-value]
            verifier=self.client.verifier,  # accepts a MAC lease: commands cost µs to check
        )
        loop = ControllerLoop(controller, Khepera(link))
        ended = threading.Event()

        def watch() -> None:
            # The context may end the slot early (stopped, disabled): stop driving then.
            while not ended.is_set():
                if stop.is_set() or self.wait_status(rid, FINAL, timeout=0.2) is not None:
                    loop.stop.set()
                    return

        watcher = threading.Thread(target=watch, name="drive-watch", daemon=True)
        watcher.start()
        error = ""
        try:
            loop.run(until=time.monotonic() + max(0.0, end - time.time()))
        except Exception:
            error = traceback.format_exc(limit=5)
        finally:
            ended.set()
            link.close(stop=True)
        reason = "the controller raised an exception" if error else "slot over"
        if stop.is_set():
            reason = "interrupted"
        self._report_end(rid, reason, error)
        if stop.is_set():
            self.cancel_quietly(rid)
            return DriveResult(rid, "interrupted", reason, loop.iterations, error)
        final = self.wait_status(rid, FINAL, timeout=2.0)
        if final is None:  # the end's event missed (or late): the context says how it ended
            try:
                asked = self.request_status(rid)
            except LabError as exc:
                log.info("could not ask how %s ended: %s", rid, exc)
                asked = None
            final = asked.status if asked is not None and asked.ended else None
        if final is None:
            return DriveResult(rid, "finished", reason, loop.iterations, error)
        return DriveResult(rid, final.status, final.reason, loop.iterations, error)

    def _report_end(self, rid: str, reason: str, error: str) -> None:
        session = self.client.session
        if session is None:
            return
        key = keys.ctx_output(self.client.realm, self.ctx)
        lines = [line[:1000] for line in error.splitlines()][:100]
        try:
            self.client.z.put(
                key,
                session.seal(
                    key, ControllerOutput(request_id=rid, lines=lines, done=True, reason=reason)
                ),
                **qos.of(keys.ctx_output),
            )
        except Exception as exc:  # the session is closing
            log.debug("could not report the end of %s: %s", rid, exc)

    def cancel_quietly(self, rid: str) -> None:
        try:
            self.cancel(rid)
        except LabError as exc:
            log.debug("cancel %s: %s", rid, exc)
