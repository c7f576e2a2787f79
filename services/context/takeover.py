"""The take-over desk: a teacher taking over a student's running robot, and handing it back.

A part of the agent context, beside the queue desk, on the state they share
(:class:`~services.context.context_state.ContextState`). The design uses the
lease machinery as it is: a world obeys the
commands of the one session its agent's lease names, and of two leases with
different ids keeps the one with the later start.

- **Take over** (:class:`~common.messages.TakeOver`, the manage right: the
  owner or ``kick`` in the context): the running slot stays, paused, not
  ended. The context signs a second lease for the same robot, held by the
  teacher's session (a fresh id and MAC key, start now, end the student's
  slot end) and publishes it instead of the student's, every second as
  usual. The world replaces the student's lease with it, so the student's
  controller (in the runner's sandbox, or ``wart control``) goes on reading
  its sensors while every command it sends is refused; the teacher's
  commands (the page's keys, or the teacher's own controller) are obeyed.
- **Hand back** (:class:`~common.messages.HandBack`, any manager; also when
  the teacher's session leaves or is revoked): the student's own lease is
  published again, same id and key, its start moved to now (the later start
  wins in the world), so the controller drives again for the rest of its
  slot. The slot's clock runs on during a take-over: the queue behind it is
  not delayed, and the runner's sandbox keeps its end.

Each step is a ``running`` :class:`~common.messages.RequestStatus` with
``takeover`` set and the reason in words ("your robot is driven by <teacher>
since ...; your controller is paused"), which the student's clients show and
the run's recording keeps among its events; the queue state's running entry
says ``taken_by``. The context's audit trail gets ``takeover`` / ``handback``
lines, refusals included (agent_context.py).
"""

from __future__ import annotations

import logging
import secrets
import time
from collections.abc import Callable

import msgspec

from common.audit import AuditReporter
from common.auth import Principal
from common.messages import AgentEvent, HandBack, Message, OkReply, RequestStatus, TakenOver
from common.messages import TakeOver as TakeOverRequest
from common.service import RequestError
from common.world.leasemac import new_lease_key
from services.context.agent_queue import ControlJob, RunningJob
from services.context.context_state import ContextState, request_status
from services.context.lease_signer import LeaseSigner

log = logging.getLogger("wart.chat")  # the context's own logger (chat_room.py)


def _clock(at: float) -> str:
    return time.strftime("%H:%M:%S UTC", time.gmtime(at))


class TakeOverDesk:
    """Take-over and hand-back requests, on the state the context's parts share."""

    def __init__(
        self,
        state: ContextState,
        *,
        leases: LeaseSigner,
        audit: AuditReporter,
        require_manage: Callable[[Principal, str], None],
        publish: Callable[[AgentEvent], None],
        publish_lease: Callable[[RunningJob, float], None],
    ) -> None:
        """``require_manage`` is the context's manage right; ``publish`` tells the
        members an event (and records it); ``publish_lease`` publishes the lease in
        force for a run (the scheduler's: the teacher's while taken over)."""
        self.state = state
        self.leases = leases
        self.audit = audit
        self.require_manage = require_manage
        self.publish = publish
        self.publish_lease = publish_lease

    def take_over(self, principal: Principal, request: TakeOverRequest) -> Message:
        agent = request.agent
        self.require_manage(principal, f"take over {agent}")
        self.state.require_agent(agent)
        now = time.time()
        with self.state.wake:
            run = self.state.book.lines[agent].running
            if run is None or run.end <= now:
                raise RequestError(
                    "conflict",
                    f"nothing runs on {agent}: a take-over pauses a student's running "
                    "controller (queue a request to drive an idle robot)",
                )
            taken = run.taken
            if taken is not None and taken.holder_session != principal.session_id:
                raise RequestError(
                    "conflict",
                    f"{agent} is already taken over by {taken.job.user} since "
                    f"{_clock(taken.start)}: hand it back first",
                )
            if taken is None:
                teacher = ControlJob(
                    request_id=run.job.request_id,
                    agent=agent,
                    user=principal.user,
                    session_id=principal.session_id,
                    mode="remote",
                    box_key=principal.token.box_key,
                )
                taken = run.taken = RunningJob(
                    job=teacher,
                    # Its own id and key: the student's MAC key opens nothing of it, and
                    # the random part first, so a long context name never cuts it off.
                    lease_id=f"take-{secrets.token_hex(6)}.{self.state.room}"[:64],
                    holder_session=principal.session_id,
                    start=now,
                    end=run.end,
                    holder_box=principal.token.box_key,
                    lease_key=new_lease_key(),
                )
                why = f"your robot is driven by {principal.user} since {_clock(now)}; "
                why += "your controller is paused"
                if request.reason:
                    why += f" ({request.reason})"
                status = self._step(run, "taken", why)
                self.state.dirty = True
                self.state.wake.notify_all()
            else:
                status = None  # already the sender's: say so again, change nothing
        if status is not None:
            self.publish_lease(run, run.end)
            log.info("%s took %s over from %s (%s)", principal.user, agent, run.job.user, why)
            self.publish(AgentEvent(ctx=self.state.room, request=status))
        return TakenOver(
            agent=agent,
            world=self.state.world,
            request_id=run.job.request_id,
            user=run.job.user,
            since=taken.start,
            end=run.end,
        )

    def hand_back(self, principal: Principal, request: HandBack) -> Message:
        agent = request.agent
        self.require_manage(principal, f"hand {agent} back")
        self.state.require_agent(agent)
        with self.state.wake:
            run = self.state.book.lines[agent].running
            if run is None or run.taken is None:
                raise RequestError("conflict", f"{agent} is not taken over: nothing to hand back")
            teacher = run.taken.job.user
            by = "" if teacher == principal.user else f" (by {principal.user})"
            taken, status = self._give_back(run, f"{teacher} handed your robot back{by}")
        self._after_hand_back(run, taken, status)
        return OkReply(detail=f"{agent} handed back to {run.job.user}'s controller")

    def hand_back_session(self, session_id: bytes, why: str) -> None:
        """Hand back every robot a session took over (it left, or was revoked)."""
        handed: list[tuple[RunningJob, RunningJob, RequestStatus]] = []
        with self.state.wake:
            for line in self.state.book.lines.values():
                run = line.running
                taken = None if run is None else run.taken
                if run is not None and taken is not None and taken.holder_session == session_id:
                    handed.append((run, *self._give_back(run, f"{taken.job.user} {why}")))
        for run, taken, status in handed:
            # In the audit trail as the context's doing, in the teacher's name.
            where = f"agent/{self.state.room}/{run.job.agent}"
            self.audit.report(taken.job.user, "handback", where, "ok", status.reason)
            self._after_hand_back(run, taken, status)

    def _give_back(self, run: RunningJob, said: str) -> tuple[RunningJob, RequestStatus]:
        """The run's own lease in force again from now (lock held): the take-over that
        ended, and the status to tell."""
        taken = run.taken
        assert taken is not None
        now = time.time()
        run.taken = None
        run.lease_start = now
        taken.end = min(taken.end, now)
        self.state.dirty = True
        self.state.wake.notify_all()
        return taken, self._step(run, "handed_back", f"{said}: your controller drives again")

    def _after_hand_back(self, run: RunningJob, taken: RunningJob, status: RequestStatus) -> None:
        # The teacher's lease ended first, then the student's from now (the later start).
        self.leases.publish(taken, taken.end, taken.job.user)
        self.publish_lease(run, run.end)
        log.info("%s: %s", run.job.request_id, status.reason)
        self.publish(AgentEvent(ctx=self.state.room, request=status))

    def _step(self, run: RunningJob, step: str, reason: str) -> RequestStatus:
        status = request_status(run.job, "running", reason[:256], run)
        taken = run.taken
        return msgspec.structs.replace(
            status,
            takeover=step,
            taken_by=taken.job.user if taken is not None else None,
            taken_at=taken.start if taken is not None else None,
        )
