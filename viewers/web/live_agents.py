"""The robot panel's side of a live agent context: queues, uploads, output, settings.

One :class:`AgentContextLink` per joined agent context and browser user wraps
:class:`~common.client.agent_client.AgentClient` (the same client ``wart deploy``
uses) on that user's :class:`~common.client.lab_client.LabClient`, so every request is
sealed with the person's session and the context checks their rights. Its
AgentEvents arrive on Zenoh's threads and are only translated and queued
here; the page handles them on the connection's own thread.

Pure helpers (:func:`agent_rows`, :func:`check_upload`) are unit-tested
without a lab.
"""

from __future__ import annotations

import functools
import logging
import time
from collections.abc import Callable
from pathlib import Path, PurePath
from typing import TypeVar

from common import lab_errors
from common.client import lab_client as lab
from common.client.agent_client import AgentClient
from common.client.rooms import RoomHandle
from common.controller.upload_gate import PrecheckError, precheck
from common.keys import is_ident
from common.messages import (
    AgentContextState,
    ControlQueued,
    OutputLines,
    RequestStatus,
    RoomEvent,
)
from common.recording import RecordingError, read_recording
from viewers.web.adapters import (
    CONTROLLER_SUFFIXES,
    MAX_CONTROLLER_BYTES,
    AgentsEvent,
    AgentStatus,
    ArenaSettings,
    DryRunResult,
    LabError,
    LabEvent,
    OutputEvent,
    OutputSoFar,
    Queued,
    RecordingEntry,
    RequestEvent,
    SavedFile,
    plain_error,
)
from viewers.web.key_driver import KeyDriver

log = logging.getLogger("wart.viewer.agents")

T = TypeVar("T")

MAX_FILENAME = 128  # what the page keeps of an uploaded file's name


def check_upload(filename: str, content: bytes) -> tuple[str, str | None]:
    """(the file's plain name, why it is refused or None); never runs the file.

    The page's own checks (a .py name, not empty) then ``common.controller.upload_gate``, the
    same check the agent context and the runner make (size, UTF-8, syntax with
    the line, a Controller subclass), so a student hears at once, in words.
    """
    name = PurePath(str(filename).replace("\\", "/")).name[:MAX_FILENAME]
    if PurePath(name).suffix not in CONTROLLER_SUFFIXES:
        return name, f"{name or 'the file'} is not a Python file (.py)."
    if not content:
        return name, f"{name} is empty."
    if len(content) > MAX_CONTROLLER_BYTES:
        return name, (
            f"{name} is {len(content)} bytes; controllers are limited to "
            f"{MAX_CONTROLLER_BYTES // 1024} KiB."
        )
    try:
        precheck(content, name)
    except PrecheckError as exc:
        return name, str(exc)
    return name, None


def _checked_upload(agent: str, filename: str, content: bytes) -> str:
    """The file's plain name, once ``agent`` is a robot's id and the file passes
    check_upload; else LabError with why."""
    if not is_ident(agent):
        raise LabError("choose a robot first")
    name, problem = check_upload(filename, content)
    if problem:
        raise LabError(problem)
    return name


def agent_rows(
    state: AgentContextState,
    user: str,
    now: float,
    offline: frozenset[str] = frozenset(),
) -> list[AgentStatus]:
    """The context's queues as robot-panel rows, seen by ``user`` at wall time ``now``."""
    rows = []
    for line in state.agents:
        running = next((e for e in line.entries if e.position == 0), None)
        mine = next((e for e in line.entries if e.user == user), None)
        eta = None
        if mine is not None and mine.position > 0 and mine.start_eta is not None:
            eta = max(0.0, mine.start_eta - now)
        left = None
        if running is not None and running.end is not None:
            left = max(0.0, running.end - now)
        rows.append(
            AgentStatus(
                agent=line.agent,
                holder=running.user if running is not None else None,
                queue=sum(1 for e in line.entries if e.position > 0),
                my_position=mine.position if mine is not None else None,
                eta_s=eta,
                enabled=line.enabled and state.enabled,
                online=line.agent not in offline,
                my_request=mine.request_id if mine is not None else None,
                slot_left_s=left,
                taken_by=running.taken_by if running is not None else None,
                waiting=tuple(e.user for e in line.entries if e.position > 0),
            )
        )
    return rows


class AgentContextLink:
    """One user in one agent context: the AgentClient, and its events for the page."""

    def __init__(
        self,
        client: lab.LabClient,
        ctx: str,
        emit: Callable[[LabEvent], None],
        on_room: Callable[[RoomEvent], None],
    ) -> None:
        self.ctx = ctx
        self.user = client.user
        self._emit = emit
        self.agents = AgentClient(
            client,
            ctx,
            on_output=self._on_output,
            on_state=lambda _s: emit(AgentsEvent(ctx)),
            on_status=self._on_status,
            on_room=on_room,
        )
        self.driver = KeyDriver(self.agents)
        self.taken: set[str] = set()  # robots this session took over and holds

    def join(self, history: int) -> RoomHandle:
        """Join the context (chat and agent events) and read its queues once."""
        try:
            self._call(lambda: self.agents.join(history))
        except LabError:
            if self.agents.room is not None:  # joined, but the queues did not answer
                self.leave()
            raise
        room = self.agents.room
        assert room is not None
        return room

    def leave(self) -> None:
        self.driver.stop()
        self._call(self.agents.leave)

    @property
    def owner(self) -> str:
        room = self.agents.room
        return room.owner if room is not None else ""

    # Zenoh threads: translate and queue, nothing more.
    def _on_output(self, out: OutputLines) -> None:
        self._emit(
            OutputEvent(self.ctx, out.request_id, out.agent, out.user, tuple(out.lines), out.first)
        )

    def _on_status(self, status: RequestStatus) -> None:
        self._emit(
            RequestEvent(
                self.ctx,
                status.request_id,
                status.agent,
                status.user,
                status.status,
                status.reason,
                status.takeover,
            )
        )
        self._emit(AgentsEvent(self.ctx))

    # -- requests (the page's threads; each may block up to the query timeout)

    def _call(self, fn: Callable[[], T]) -> T:
        try:
            return fn()
        except lab_errors.LabError as exc:
            raise plain_error(exc) from None

    def state(self, *, fresh: bool = False) -> AgentContextState:
        state = self.agents.latest_state
        if state is None or fresh:
            state = self._call(self.agents.state)
        return state

    @property
    def world(self) -> str | None:
        state = self.agents.latest_state
        return state.world if state is not None else None

    def rows(self, offline: frozenset[str] = frozenset()) -> list[AgentStatus]:
        return agent_rows(self.state(), self.user, time.time(), offline)

    def request(self, agent: str, filename: str, source: bytes) -> Queued:
        name = _checked_upload(agent, filename, source)
        queued = self._call(
            lambda: self.agents.queue(agent, "deploy", source=source, filename=name)
        )
        return self._queued(queued)

    def cancel(self, agent: str) -> str:
        if not is_ident(agent):
            raise LabError("choose a robot first")
        rows = agent_rows(self.state(fresh=True), self.user, time.time())
        mine = next((r for r in rows if r.agent == agent and r.my_request), None)
        if mine is None or mine.my_request is None:
            raise LabError(f"you have no request on {agent}")
        rid = mine.my_request
        detail = self._call(lambda: self.agents.cancel(rid))
        self._refresh()
        return detail

    def settings(self, user_may_kick: bool) -> ArenaSettings:
        state = self.state()
        return ArenaSettings(
            slot_seconds=state.slot_seconds,
            enabled=state.enabled,
            can_manage=user_may_kick or self.owner == self.user,
            estop=state.estop,
        )

    def emergency_stop(self, engaged: bool, reason: str) -> str:
        detail = self._call(
            lambda: self.agents.emergency_stop(reason or "from the web page", release=not engaged)
        )
        self._refresh()
        return detail

    def dry_run(self, agent: str, filename: str, source: bytes) -> DryRunResult:
        name = _checked_upload(agent, filename, source)
        report = self._call(lambda: self.agents.dry_run(agent, source, filename=name))
        details = [f"robot model: {report.model}"] if report.model else []
        details += [
            f"collision at {c.at:.2f} s: {c.what}{' ' + c.ident if c.ident else ''}"
            for c in report.collisions[:5]
        ]
        if report.commands:
            details.append(f"{report.saturated} of {report.commands} wheel commands at top speed")
        details += [f"| {line}" for line in report.output[:5]]
        return DryRunResult(report.will_run, report.verdict, tuple(details), report.error_line)

    def set_slot(self, seconds: float) -> str:
        if not (1.0 <= seconds <= 3600.0):
            raise LabError("a slot lasts between 1 and 3600 seconds")
        detail = self._call(lambda: self.agents.settings(slot_seconds=seconds))
        self._refresh()
        return detail

    def stop(self, agent: str) -> str:
        if not is_ident(agent):
            raise LabError("choose a robot first")
        return self._call(lambda: self.agents.stop_agent(agent, "stopped from the web page"))

    def take_over(self, agent: str, take: bool) -> str:
        """Take ``agent`` over (its student's controller paused), or hand it back."""
        if not is_ident(agent):
            raise LabError("choose a robot first")
        if take:
            taken = self._call(lambda: self.agents.take_over(agent, "from the web page"))
            self.taken.add(agent)
            self._refresh()
            return f"{agent} taken over from {taken.user}: their controller is paused"
        self.driver.stop()
        detail = self._call(lambda: self.agents.hand_back(agent))
        self.taken.discard(agent)
        self._refresh()
        return detail

    def hand_back_all(self, why: str) -> None:
        """Hand back every robot this session holds: nobody can drive them from it any more
        (the viewer that held it stops), and their students' controllers should drive again."""
        self.driver.stop()
        for agent in sorted(self.taken):
            try:
                self._call(functools.partial(self.agents.hand_back, agent))
                log.info(
                    "%s's take-over of %s in %s handed back: %s", self.user, agent, self.ctx, why
                )
            except LabError as exc:
                log.info("handing %s back in %s: %s", agent, self.ctx, exc)
        self.taken.clear()

    def drive(self, agent: str, left: int, right: int) -> None:
        if not self.agents.is_taken_by(agent, self.user):
            raise LabError(f"take {agent} over first")
        world = self.world
        assert world is not None  # a state was read: the take-over came from it
        self.driver.set(world, agent, left, right)

    def set_enabled(self, enabled: bool, agent: str | None) -> str:
        if agent is not None and not is_ident(agent):
            raise LabError("choose a robot first")
        detail = self._call(lambda: self.agents.settings(enabled=enabled, agent=agent))
        self._refresh()
        return detail

    # -- my files (the editor); the context files them under my session's user

    def list_files(self) -> list[SavedFile]:
        listing = self._call(self.agents.list_files)
        return [SavedFile(f.name, f.size, f.saved_at) for f in listing.files]

    def read_file(self, name: str) -> bytes:
        return self._call(lambda: self.agents.read_file(name)).source

    def save_file(self, name: str, source: bytes) -> str:
        return self._call(lambda: self.agents.save_file(name, source))

    # -- my recordings (the context lists and serves only my own without the manage right)

    def output_so_far(self, request_id: str) -> OutputSoFar:
        kept = self._call(lambda: self.agents.output_so_far(request_id))
        return OutputSoFar(kept.first, tuple(kept.lines))

    def recordings(self) -> list[RecordingEntry]:
        listing = self._call(self.agents.recordings)
        mine = [
            RecordingEntry(
                name=r.name,
                agent=r.agent,
                start=r.start,
                size=r.size,
                status=r.status,
                reason=r.reason,
                duration_s=r.duration_s,
                distance_mm=r.distance_mm,
            )
            for r in listing.recordings
            if r.user == self.user
        ]
        return sorted(mine, key=lambda r: r.start, reverse=True)

    def fetch_recording(self, name: str, dest: Path) -> Path:
        if not is_ident(name):
            raise LabError(f"{name!r} is not a recording's name")
        return self._call(lambda: self.agents.download(name, dest))

    def promote(self, agent: str, recording: Path) -> Queued:
        """Queue a recorded deploy run's file on ``agent`` here (a real arena's robot)."""
        if not is_ident(agent):
            raise LabError("choose a robot first")
        try:
            rec = read_recording(recording)
        except RecordingError as exc:
            raise LabError(str(exc)) from None
        return self._queued(self._call(lambda: self.agents.promote(rec, agent)))

    def _queued(self, queued: ControlQueued) -> Queued:
        """A request the context queued, as the page shows it (the queues read again)."""
        now = time.time()
        eta = None if queued.start_eta is None else max(0.0, queued.start_eta - now)
        self._refresh()
        return Queued(queued.request_id, queued.agent, queued.position, eta, queued.slot_seconds)

    def _refresh(self) -> None:
        """Read the queues now so the page shows a change at once (events follow anyway)."""
        try:
            self.agents.state()
        except lab_errors.LabError as exc:
            log.debug("queues of %s: %s", self.ctx, exc)
        self._emit(AgentsEvent(self.ctx))
