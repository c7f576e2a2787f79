"""Per-agent FIFO queues of controller requests (the thesis's AgentControlRequest), pure logic.

No Zenoh and no clock of its own: the agent context calls these methods under
its lock with the current wall-clock time, and does the I/O (leases, the
runner, events) itself. Each agent has at most one running request (holding
the lease) and a FIFO of waiting ones; a request runs for the slot length in
force when it starts.
"""

from __future__ import annotations

import itertools
import secrets
from collections import deque
from dataclasses import dataclass, field

import msgspec

from common.messages import AgentQueue, QueueEntry, RequestStatus, RunMode

# How many ended requests the book remembers, so a client that missed a request's
# last event can still ask how it ended. Per user first: one student queueing and
# cancelling in a loop pushes out only their own; then overall, which bounds the
# saved file (a few hundred bytes each) at a size rewritten cheaply on each change.
ENDED_PER_USER = 16
ENDED_KEPT = 512


@dataclass
class ControlJob:
    """One queued request: who, for which agent, how it will run."""

    request_id: str
    agent: str
    user: str
    session_id: bytes  # the requester's session (the lease holder in remote mode)
    mode: RunMode
    source: bytes = b""
    filename: str = "controller.py"
    box_key: bytes = b""  # the requester's session box key (a MAC lease's key is sealed to it)


@dataclass
class RunningJob:
    job: ControlJob
    lease_id: str
    holder_session: bytes  # the requester's (remote) or the runner's (deploy) session
    start: float
    end: float
    holder_box: bytes = b""  # the holder session's box key
    lease_key: bytes = b""  # K of a MAC lease (common/world/leasemac.py); sealed per publication
    # (holder box, world box) -> (K sealed to the holder, K sealed to the world): sealed
    # once, so a republished lease is byte-identical and the holder skips unsealing it.
    sealed: dict[tuple[bytes, bytes], tuple[bytes, bytes]] = field(default_factory=dict)
    # A teacher's take-over (services/context/takeover.py): their lease, a run of its own
    # (job.user the teacher, start when taken), in force instead of this one's until
    # handed back. The world keeps the lease with the later start, so a run handed back
    # republishes its own lease from ``lease_start`` (the hand-back) on.
    taken: RunningJob | None = None
    lease_start: float = 0.0


class EndedRequest(msgspec.Struct, frozen=True):
    """A request's last status and when it ended (wall-clock s)."""

    status: RequestStatus
    ended_at: float


@dataclass
class AgentLine:
    agent: str
    type: str
    enabled: bool = True
    waiting: deque[ControlJob] = field(default_factory=deque)
    running: RunningJob | None = None


_counter = itertools.count(1)


def new_request_id(agent: str) -> str:
    """Unique, readable, and one key chunk (lease ids derive from it)."""
    return f"{agent}-{next(_counter)}-{secrets.token_hex(3)}"


class QueueBook:
    """Every agent's queue. Not thread-safe: the context holds its lock around calls."""

    def __init__(self, slot_seconds: float) -> None:
        self.slot_seconds = slot_seconds
        self.enabled = True
        # The host's emergency stop ("emergency stop by <who>...", "" when none): no
        # slot starts while it holds; waiting requests keep their places.
        self.estop = ""
        self.lines: dict[str, AgentLine] = {}
        self.ended: dict[str, EndedRequest] = {}  # request id -> its end, oldest first

    # -- agents

    def set_agents(self, agents: dict[str, str]) -> list[ControlJob]:
        """Adopt the world's agent list (id -> type); returns waiting jobs of vanished agents."""
        gone: list[ControlJob] = []
        for agent in list(self.lines):
            if agent not in agents:
                line = self.lines.pop(agent)
                gone.extend(line.waiting)
                if line.running is not None:
                    gone.append(line.running.job)
        for agent, kind in agents.items():
            known = self.lines.get(agent)
            if known is None:
                self.lines[agent] = AgentLine(agent=agent, type=kind)
            else:
                known.type = kind
        return gone

    def can_run(self, agent: str) -> bool:
        line = self.lines.get(agent)
        return bool(line and line.enabled and self.enabled)

    # -- requests

    def add(self, job: ControlJob) -> int:
        """Queue ``job``; its position (1 = next)."""
        line = self.lines[job.agent]
        line.waiting.append(job)
        return len(line.waiting)

    def find(self, request_id: str) -> tuple[AgentLine, ControlJob, bool] | None:
        """(line, job, running) of a request, or None."""
        for line in self.lines.values():
            if line.running is not None and line.running.job.request_id == request_id:
                return line, line.running.job, True
            for job in line.waiting:
                if job.request_id == request_id:
                    return line, job, False
        return None

    def remove_waiting(self, request_id: str) -> ControlJob | None:
        for line in self.lines.values():
            for job in line.waiting:
                if job.request_id == request_id:
                    line.waiting.remove(job)
                    return job
        return None

    def jobs_of_session(self, session_id: bytes) -> list[tuple[ControlJob, bool]]:
        out: list[tuple[ControlJob, bool]] = []
        for line in self.lines.values():
            if line.running is not None and line.running.job.session_id == session_id:
                out.append((line.running.job, True))
            out.extend((job, False) for job in line.waiting if job.session_id == session_id)
        return out

    def next_to_start(self, agent: str) -> ControlJob | None:
        line = self.lines[agent]
        if line.running is not None or not line.waiting or not self.can_run(agent) or self.estop:
            return None
        return line.waiting.popleft()

    def expired(self, now: float) -> list[RunningJob]:
        return [
            line.running
            for line in self.lines.values()
            if line.running is not None and now >= line.running.end
        ]

    def record_end(self, status: RequestStatus, at: float) -> None:
        """Remember how a request ended; the oldest ends beyond the bounds are forgotten."""
        self.ended.pop(status.request_id, None)
        self.ended[status.request_id] = EndedRequest(status, at)
        mine = [rid for rid, end in self.ended.items() if end.status.user == status.user]
        for rid in mine[: max(0, len(mine) - ENDED_PER_USER)]:
            del self.ended[rid]
        while len(self.ended) > ENDED_KEPT:
            del self.ended[next(iter(self.ended))]

    # -- what users see

    def eta(self, agent: str, position: int, now: float) -> float | None:
        """When the waiting request at ``position`` (1 = next) should start; None if disabled."""
        line = self.lines[agent]
        if not self.can_run(agent) or self.estop:
            return None
        start = max(now, line.running.end) if line.running is not None else now
        return start + (position - 1) * self.slot_seconds

    def agent_queues(self, now: float) -> list[AgentQueue]:
        out = []
        for agent in sorted(self.lines):
            line = self.lines[agent]
            entries: list[QueueEntry] = []
            if line.running is not None:
                job = line.running.job
                entries.append(
                    QueueEntry(
                        request_id=job.request_id,
                        user=job.user,
                        mode=job.mode,
                        position=0,
                        start_eta=line.running.start,
                        end=line.running.end,
                        taken_by=line.running.taken.job.user if line.running.taken else None,
                        taken_at=line.running.taken.start if line.running.taken else None,
                    )
                )
            for position, job in enumerate(line.waiting, start=1):
                entries.append(
                    QueueEntry(
                        request_id=job.request_id,
                        user=job.user,
                        mode=job.mode,
                        position=position,
                        start_eta=self.eta(agent, position, now),
                    )
                )
            out.append(
                AgentQueue(agent=agent, type=line.type, enabled=line.enabled, entries=entries)
            )
        return out


# -- what survives a restart of the context


class _SavedRun(msgspec.Struct):
    job: ControlJob
    lease_id: str
    holder_session: bytes
    start: float
    end: float
    holder_box: bytes = b""
    lease_key: bytes = b""
    lease_start: float = 0.0
    taken: _SavedRun | None = None  # a take-over in force survives a restart too


def _saved_run(run: RunningJob) -> _SavedRun:
    return _SavedRun(
        run.job,
        run.lease_id,
        run.holder_session,
        run.start,
        run.end,
        run.holder_box,
        run.lease_key,
        run.lease_start,
        None if run.taken is None else _saved_run(run.taken),
    )


def _running_job(r: _SavedRun) -> RunningJob:
    return RunningJob(
        r.job,
        r.lease_id,
        r.holder_session,
        r.start,
        r.end,
        r.holder_box,
        r.lease_key,
        taken=None if r.taken is None else _running_job(r.taken),
        lease_start=r.lease_start,
    )


class _SavedLine(msgspec.Struct):
    agent: str
    type: str
    enabled: bool
    waiting: list[ControlJob]
    running: _SavedRun | None = None


class _SavedBook(msgspec.Struct):
    version: int
    slot_seconds: float
    enabled: bool
    lines: list[_SavedLine]
    estop: str = ""  # a held emergency stop survives a restart of the context
    # How requests ended, so a client that missed the end (or the restart that came
    # with it, "the agent context stopped") is still told after a restart.
    ended: list[EndedRequest] = msgspec.field(default_factory=list)


_BOOK_VERSION = 1
_book_decoder = msgspec.msgpack.Decoder(_SavedBook)


def save_book(book: QueueBook) -> bytes:
    """The queues, their settings, the running slots (with their lease keys) and the
    record of ended requests, as bytes."""
    lines = []
    for line in book.lines.values():
        run = line.running
        saved_run = None if run is None else _saved_run(run)
        lines.append(_SavedLine(line.agent, line.type, line.enabled, list(line.waiting), saved_run))
    return msgspec.msgpack.encode(
        _SavedBook(
            _BOOK_VERSION,
            book.slot_seconds,
            book.enabled,
            lines,
            book.estop,
            list(book.ended.values()),
        )
    )


def load_book(data: bytes) -> QueueBook:
    """A QueueBook from :func:`save_book`'s bytes; ValueError if they are not one."""
    try:
        saved = _book_decoder.decode(data)
    except msgspec.DecodeError as exc:
        raise ValueError(f"not a saved queue book: {exc}") from None
    if saved.version != _BOOK_VERSION:
        raise ValueError(f"saved queue book version {saved.version}, expected {_BOOK_VERSION}")
    book = QueueBook(saved.slot_seconds)
    book.enabled = saved.enabled
    book.estop = saved.estop
    book.ended = {end.status.request_id: end for end in saved.ended}
    for line in saved.lines:
        running = None if line.running is None else _running_job(line.running)
        book.lines[line.agent] = AgentLine(
            line.agent, line.type, line.enabled, deque(line.waiting), running
        )
    return book
