"""An agent context's answer to "where is my request now?" (``ctx/<ctx>/status``).

The context tells each of a request's statuses once, as an AgentEvent on
``ctx/<ctx>/events``. A client that missed the last one (it subscribed late,
its link or its router blipped) would see only that the request left the
queues, and could not tell "finished" from "the runner crashed" from "lost".
It asks here instead, and the context answers from its queues and from the
queue book's bounded record of ended requests (saved with the queues, so a
restart of the context keeps it).

Rights: ``join`` in the context, as for reading the queues; then a user reads
their own requests, the context's managers (its owner, or ``kick`` there)
anyone's. Another user's request is ``forbidden`` rather than hidden: its id
and owner are public in the queue state, how it ended is not. An id the
context never saw or has forgotten is answered "unknown" to anyone, which
tells nothing.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal

from common import acl
from common.auth import AuthError, Principal, Verifier
from common.messages import RequestStatus, RequestStatusQuery, RequestStatusReply
from common.service import RequestError
from services.context.agent_queue import ControlJob, QueueBook
from services.context.chat_room import room_allows


def look_up(
    book: QueueBook, starting: Mapping[str, ControlJob], request_id: str, now: float
) -> RequestStatusReply:
    """Where ``request_id`` stands in ``book`` (the caller holds ContextState.lock).

    ``starting``: requests taken off their queue whose slot is being set up (the
    runner asked for a sandbox): next, not yet running.
    """
    found = book.find(request_id)
    if found is not None:
        line, job, running = found
        if running:
            run = line.running
            assert run is not None
            status = _status(job, "running", start=run.start, end=run.end)
            return RequestStatusReply(request_id=request_id, at=now, status=status)
        position = next(i for i, j in enumerate(line.waiting, start=1) if j is job)
        return RequestStatusReply(
            request_id=request_id,
            at=now,
            status=_status(job, "queued"),
            position=position,
            start_eta=book.eta(job.agent, position, now),
        )
    next_up = starting.get(request_id)
    if next_up is not None:
        return RequestStatusReply(
            request_id=request_id,
            at=now,
            status=_status(next_up, "queued"),
            position=1,
            start_eta=now,
        )
    ended = book.ended.get(request_id)
    if ended is not None:
        return RequestStatusReply(
            request_id=request_id, at=now, status=ended.status, ended_at=ended.ended_at
        )
    return RequestStatusReply(request_id=request_id, at=now)


def _status(
    job: ControlJob,
    status: Literal["queued", "running"],
    *,
    start: float | None = None,
    end: float | None = None,
) -> RequestStatus:
    return RequestStatus(
        request_id=job.request_id,
        agent=job.agent,
        user=job.user,
        status=status,
        start=start,
        end=end,
    )


class RequestStatusDesk:
    """Serves ``RequestStatusQuery``: opens the envelope, checks the rights, answers."""

    def __init__(
        self,
        ctx: str,
        owner: str,
        verifier: Verifier,
        look_up: Callable[[str], RequestStatusReply],
        *,
        restricted: bool = False,
    ) -> None:
        self.ctx = ctx
        self.owner = owner
        self.scope = acl.context_scope(ctx)
        self.verifier = verifier
        self.look_up = look_up
        self.restricted = restricted

    def answer(self, key: str, payload: Any) -> RequestStatusReply:
        """The reply to one query; AuthError / MessageError / RequestError otherwise
        (the service's guard turns each into an ErrorReply and goes on serving)."""
        principal, query = self.verifier.open(key, payload, RequestStatusQuery)
        if not self._allows(principal, "join"):
            raise AuthError(
                "forbidden",
                f"user {principal.user} does not have the 'join' permission in {self.ctx} "
                "to see the status of requests",
            )
        reply = self.look_up(query.request_id)
        status = reply.status
        mine = status is None or status.user == principal.user
        if not mine and not self._allows(principal, "kick"):
            assert status is not None
            raise RequestError(
                "forbidden",
                f"request {query.request_id} is {status.user}'s: only they, the owner of "
                f"{self.ctx} or a user with 'kick' there may see its status",
            )
        return reply

    def _allows(self, principal: Principal, permission: str) -> bool:
        return room_allows(
            principal, permission, owner=self.owner, scope=self.scope, restricted=self.restricted
        )
