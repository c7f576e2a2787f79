"""The queue desk of an agent context: queue, cancel, stop, settings, the host's
emergency stop, and the dry run before queueing.

Each request checks the sender's rights, changes the queues (the context's
:class:`~services.context.context_state.ContextState`) under their lock and
wakes the scheduler (slots.py), which starts and ends the slots.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from common import acl, keys, qos
from common.auth import Principal, Verifier
from common.controller.upload_gate import PrecheckError, precheck
from common.messages import (
    AgentEvent,
    CancelControl,
    ContextSettings,
    ControlQueued,
    ControlRequest,
    DryRun,
    DryRunReport,
    DryRunRequest,
    EmergencyStop,
    Message,
    OkReply,
    StopControl,
    WorldStop,
)
from common.service import RequestError
from services.context.agent_queue import ControlJob, new_request_id
from services.context.context_state import ContextState, request_status
from services.context.runner_link import RunnerLink

log = logging.getLogger("wart.chat")  # the context's own logger (chat_room.py)

MAX_WAITING_PER_USER = 4
DRY_RUN_WAIT_S = 25.0  # the runner's wall-clock limit (20 s) and the sandbox's start


class QueueDesk:
    """Requests that change the queues, on the state the context's parts share."""

    def __init__(
        self,
        state: ContextState,
        *,
        session: zenoh.Session,
        realm: str,
        restricted: bool,
        verifier: Verifier,
        seal: Callable[[str, Message], bytes],
        runner_link: RunnerLink,
        require_member: Callable[[Principal], None],
        require_manage: Callable[[Principal, str], None],
        manages: Callable[[Principal], bool],
        publish: Callable[[AgentEvent], None],
        log: logging.Logger,
    ) -> None:
        """``seal`` seals with the context's current session; ``publish`` tells the
        members an event (and records it); ``require_member``, ``require_manage`` and
        ``manages`` are the context's rights (its chat room's members, its managers)."""
        self.state = state
        self.session = session
        self.realm = realm
        self.restricted = restricted
        self.verifier = verifier
        self.seal = seal
        self.runner_link = runner_link
        self.require_member = require_member
        self.require_manage = require_manage
        self.manages = manages
        self.publish = publish
        self.log = log
        self._stop_lock = threading.Lock()  # orders the world stops this context seals

    def queue(self, principal: Principal, request: ControlRequest) -> Message:
        self.require_member(principal)
        permission = "control" if request.mode == "remote" else "deploy"
        principal.require(
            permission,
            f"{'drive' if request.mode == 'remote' else 'deploy a controller on'} {request.agent}",
            scope=acl.agent_scope(self.state.room, request.agent),
            restricted=self.restricted,
        )
        self.state.require_agent(request.agent)
        if request.mode == "deploy":
            try:
                precheck(request.source, request.filename)
            except PrecheckError as exc:
                raise RequestError("bad_request", str(exc)) from None
        elif request.source:
            raise RequestError("bad_request", "a remote request carries no source")
        job = ControlJob(
            request_id=new_request_id(request.agent),
            agent=request.agent,
            user=principal.user,
            session_id=principal.session_id,
            box_key=principal.token.box_key,
            mode=request.mode,
            source=request.source,
            filename=request.filename,
        )
        now = time.time()
        with self.state.wake:
            if not self.state.book.can_run(request.agent):
                raise RequestError(
                    "forbidden",
                    f"remote control of {request.agent} is disabled in {self.state.room} for now",
                )
            mine = [j for j, _ in self.state.book.jobs_of_session(principal.session_id)]
            if any(j.agent == request.agent for j in mine):
                raise RequestError(
                    "conflict", f"you already have a request on {request.agent}: cancel it first"
                )
            waiting = sum(
                1
                for line in self.state.book.lines.values()
                for j in line.waiting
                if j.user == principal.user
            )
            if waiting >= MAX_WAITING_PER_USER:
                raise RequestError(
                    "rate_limited", f"at most {MAX_WAITING_PER_USER} waiting requests per user"
                )
            position = self.state.book.add(job)
            eta = self.state.book.eta(request.agent, position, now)
            self.state.dirty = True
            self.state.wake.notify_all()
        log.info("%s queued %s (%s) at %d", principal.user, job.request_id, job.mode, position)
        self.publish(
            AgentEvent(ctx=self.state.room, request=request_status(job, "queued")),
        )
        return ControlQueued(
            request_id=job.request_id,
            agent=job.agent,
            position=position,
            start_eta=eta,
            slot_seconds=self.state.book.slot_seconds,
        )

    def on_dry_run(self, query: zenoh.Query) -> Message:
        """A dry run of a controller on an agent: the same rights and check as queueing it."""
        principal, request = self.verifier.open(str(query.key_expr), query.payload, DryRunRequest)
        self.require_member(principal)
        principal.require(
            "deploy",
            f"dry-run a controller on {request.agent}",
            scope=acl.agent_scope(self.state.room, request.agent),
            restricted=self.restricted,
        )
        self.state.require_agent(request.agent)
        try:
            precheck(request.source, request.filename)
        except PrecheckError as exc:
            raise RequestError("bad_request", str(exc)) from None
        report: DryRunReport = self.runner_link.dry_run(
            DryRun(
                ctx=self.state.room,
                world=self.state.world,
                agent=request.agent,
                user=principal.user,
                source=request.source,
                filename=request.filename,
                seconds=request.seconds,
            ),
            timeout=DRY_RUN_WAIT_S,
        )
        log.info(
            "%s dry-ran %s on %s: %s",
            principal.user,
            request.filename,
            request.agent,
            report.verdict,
        )
        return report

    def cancel(self, principal: Principal, request: CancelControl) -> Message:
        with self.state.wake:
            found = self.state.book.find(request.request_id)
            if found is None:
                raise RequestError(
                    "not_found", f"no request {request.request_id} in {self.state.room}"
                )
            _, job, running = found
            if job.user != principal.user and not self.manages(principal):
                raise RequestError("forbidden", f"request {request.request_id} is not yours")
            why = f"cancelled by {principal.user}"
            final = None
            if not running:
                self.state.book.remove_waiting(job.request_id)
                final = self.state.ended(job, "cancelled", why)
                self.state.dirty = True
            else:
                self.state.finish_soon(job.request_id, "cancelled", why)
            self.state.wake.notify_all()
        if final is not None:
            self.publish(AgentEvent(ctx=self.state.room, request=final))
        whose = "your" if job.user == principal.user else f"{job.user}'s"
        what = "run" if running else "waiting request"
        return OkReply(detail=f"{whose} {what} on {job.agent} cancelled")

    def stop_agent(self, principal: Principal, request: StopControl) -> Message:
        self.require_manage(principal, f"stop the controller on {request.agent}")
        self.state.require_agent(request.agent)
        with self.state.wake:
            run = self.state.book.lines[request.agent].running
            if run is None:
                return OkReply(detail=f"nothing runs on {request.agent}")
            why = f"stopped by {principal.user}" + (f": {request.reason}" if request.reason else "")
            self.state.finish_soon(run.job.request_id, "cancelled", why)
            self.state.wake.notify_all()
        return OkReply(detail=f"stopping {run.job.user}'s controller on {request.agent}")

    def emergency_stop(self, principal: Principal, request: EmergencyStop) -> Message:
        """Stop (or release) every robot of the arena: the running controllers end now,
        the world stops every robot and refuses commands, no slot starts until released.

        The world is told first and directly (not by the scheduler's next turn):
        its robots stop whether or not the runner or a student's machine obeys.
        """
        what = "stop every robot" if request.engaged else "release the emergency stop"
        self.require_manage(principal, what)
        with self.state.wake:
            if request.engaged == bool(self.state.book.estop):
                detail = self.state.book.estop or "no emergency stop is in force"
                return OkReply(detail=f"nothing changed: {detail}")
            if request.engaged:
                why = f"emergency stop by {principal.user}" + (
                    f": {request.reason}" if request.reason else ""
                )
                why = why[:256]  # a RequestStatus reason's limit
                self.state.book.estop = why
                ended = [run.job.request_id for run in self.state.running()]
                for request_id in ended:
                    self.state.finish_soon(request_id, "cancelled", why)
            else:
                self.state.book.estop = ""
                ended = []
            self.state.dirty = True
            self.state.wake.notify_all()
        self.publish_world_stop(request.engaged, principal.user)
        if request.engaged:
            log.warning("%s: ended %s", why, ", ".join(ended) or "nothing running")
            return OkReply(
                detail=f"emergency stop: every robot stopped, {len(ended)} "
                f"controller{'' if len(ended) == 1 else 's'} ended; "
                "no slot starts until you release it"
            )
        log.warning("emergency stop released by %s", principal.user)
        return OkReply(detail="emergency stop released: waiting requests start again")

    def publish_world_stop(self, engaged: bool | None, by: str) -> None:
        """Tell the world the stop in force (``engaged`` None: republish it, if one holds).

        Sealed and put under one lock, re-reading the book inside it: the world obeys
        the newest stop by its send time, so a republication sealed after a release
        would stop the arena again.
        """
        key = keys.world_estop(self.realm, self.state.world)
        with self._stop_lock:
            with self.state.lock:
                why = self.state.book.estop
            if engaged is None and not why:
                return
            message = WorldStop(engaged=bool(why), by=by, reason=why[:256])
            try:
                self.session.put(key, self.seal(key, message), **qos.of(keys.world_estop))
            except Exception as exc:  # the session closing at shutdown
                self.log.warning("could not tell world %s of the stop: %s", self.state.world, exc)

    def change_settings(self, principal: Principal, request: ContextSettings) -> Message:
        self.require_manage(principal, "change the settings")
        if request.agent is not None:
            self.state.require_agent(request.agent)
        done: list[str] = []
        with self.state.wake:
            if request.slot_seconds is not None:
                self.state.book.slot_seconds = request.slot_seconds
                done.append(f"slots of {request.slot_seconds:g} s from the next one")
            if request.enabled is not None:
                if request.agent is not None:
                    self.state.book.lines[request.agent].enabled = request.enabled
                    lines = [self.state.book.lines[request.agent]]
                else:
                    self.state.book.enabled = request.enabled
                    lines = list(self.state.book.lines.values())
                where = request.agent or "every agent"
                done.append(f"remote control {'on' if request.enabled else 'off'} for {where}")
                if not request.enabled:
                    for line in lines:
                        if line.running is not None:
                            self.state.finish_soon(
                                line.running.job.request_id,
                                "cancelled",
                                f"remote control disabled by {principal.user}",
                            )
            self.state.dirty = True
            self.state.wake.notify_all()
        log.info("%s changed the settings: %s", principal.user, "; ".join(done))
        return OkReply(detail="; ".join(done) or "nothing changed")
