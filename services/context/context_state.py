"""What the parts of an agent context share: its queues, their lock, the runs in flight.

The queue desk (queue_requests.py), the slot scheduler (slots.py) and the
take-over desk (takeover.py) each hold this one object and change it under
its lock; its condition wakes the scheduler when something changed. Requests
that leave the queues are recorded here (:meth:`ContextState.ended`), so a
client that missed the last event asks and gets the same answer.
"""

from __future__ import annotations

import threading
import time

from common.messages import AgentContextState, RequestStatus, RequestStatusReply
from common.service import RequestError
from services.context.agent_queue import ControlJob, QueueBook, RunningJob
from services.context.request_status import look_up

RECENT_RUNS = 64  # runs kept after their end, for output lines that trail it


class ContextState:
    """One agent context's queues and runs, shared by its parts under one lock."""

    def __init__(self, room: str, world: str, book: QueueBook) -> None:
        self.room = room
        self.world = world
        self.book = book
        self.lock = threading.RLock()
        self.wake = threading.Condition(self.lock)  # notified when the scheduler has work
        # Set when the context stops: the scheduler's loop and a runner's check end.
        self.halt = threading.Event()
        # The queues changed: the scheduler saves them and publishes the state next turn.
        self.dirty = True
        self.end_reasons: dict[str, tuple[str, str]] = {}  # request id -> (status, reason)
        self.recent: dict[str, RunningJob] = {}  # runs that ended lately, for trailing output
        self.starting: dict[str, ControlJob] = {}  # off their queue, their slot being set up

    def require_agent(self, agent: str) -> None:
        with self.lock:
            known = agent in self.book.lines
            names = ", ".join(sorted(self.book.lines))
        if not known and not names:
            raise RequestError(
                "not_found",
                f"world {self.world} has not answered yet (is its engine or bridge running?): "
                "try again in a moment",
            )
        if not known:
            raise RequestError(
                "not_found", f"no agent {agent} in world {self.world} (agents: {names})"
            )

    def running(self) -> list[RunningJob]:
        """The runs in force, one per busy agent."""
        with self.lock:
            return [line.running for line in self.book.lines.values() if line.running]

    def finish_soon(self, request_id: str, status: str, reason: str) -> None:
        """Make a running request end at the scheduler's next turn (lock held)."""
        found = self.book.find(request_id)
        if found is None or not found[2]:
            return
        line = found[0]
        assert line.running is not None
        self.end_reasons.setdefault(request_id, (status, reason))
        line.running.end = min(line.running.end, time.time())

    def ended(
        self, job: ControlJob, status: str, reason: str, run: RunningJob | None = None
    ) -> RequestStatus:
        """A request's last status, recorded in the book before anyone is told: a client
        that misses the event asks (``ctx/<ctx>/status``) and gets the same answer.

        Called where the request leaves the queues, under the same hold of the lock.
        For a run, ``start`` and ``end`` are its slot's start and its actual end.
        """
        now = time.time()
        final = RequestStatus(
            request_id=job.request_id,
            agent=job.agent,
            user=job.user,
            status=status,  # type: ignore[arg-type]
            reason=reason[:256],  # a RequestStatus reason's limit
            start=run.start if run else None,
            end=min(run.end, now) if run else None,
        )
        with self.lock:
            self.book.record_end(final, now)
            self.dirty = True
        return final

    def remember_ended_run(self, run: RunningJob) -> None:
        """Keep ``run`` for the output lines that trail its end (lock held): the last
        prints, a traceback come within a second or two, so the newest few are plenty."""
        self.recent[run.job.request_id] = run
        while len(self.recent) > RECENT_RUNS:
            self.recent.pop(next(iter(self.recent)))

    def look_up(self, request_id: str) -> RequestStatusReply:
        with self.lock:
            return look_up(self.book, self.starting, request_id, time.time())

    def state_message(self) -> AgentContextState:
        now = time.time()
        with self.lock:
            return AgentContextState(
                ctx=self.room,
                world=self.world,
                slot_seconds=self.book.slot_seconds,
                enabled=self.book.enabled,
                agents=self.book.agent_queues(now),
                at=now,
                estop=self.book.estop,
            )


def request_status(
    job: ControlJob, status: str, reason: str = "", run: RunningJob | None = None
) -> RequestStatus:
    """A status of ``job`` to tell (not its end: :meth:`ContextState.ended` records that)."""
    return RequestStatus(
        request_id=job.request_id,
        agent=job.agent,
        user=job.user,
        status=status,  # type: ignore[arg-type]
        reason=reason,
        start=run.start if run else None,
        end=run.end if run else None,
    )
