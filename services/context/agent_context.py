"""``wart context agent --world W --name CTX``: an agent context (the thesis's AgentContext, 7.4.2).

Everything a chat room has (it *is* a :class:`~services.context.chat_room.ChatRoom`:
members, chat, history, kick), plus the agents of one world (simulated by an
engine or real behind a bridge: the same keys, so it does not care which) and
a FIFO queue of controller requests per agent. The request at the head runs
for one slot under a :class:`~common.messages.Lease` this context signs and
the world enforces; then it stops and the next one starts.

Two run modes: ``remote`` (the requester's own session drives, ``wart
control``) and ``deploy`` (the source is uploaded and a runner drives it in
its sandbox; the lease names the runner's session). Output of the running
controller comes in on ``ctx/<ctx>/output`` from the lease holder and goes
out to members as :class:`~common.messages.AgentEvent`.

MAC leases (common/leasemac.py): when the world's snapshot carries an
identity token the registry signed with the ``world`` permission, each lease
also carries a fresh per-lease key sealed to the holder and to that world,
so the holder's commands are MACed (µs to check) rather than signed.

Rights (registry ACL, scopes ``ctx/<ctx>`` and ``agent/<ctx>/<agent>``):
``join``; ``control`` (remote) or ``deploy`` (upload) on the agent; the
owner, or ``kick`` in the context, *manages*: slot length, stop, enable or
disable remote control for the context or one agent, cancel anyone's request.
"""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path
from typing import Any

import msgspec
import zenoh

from common import acl, keys
from common.auth import AuthError, Principal
from common.files import write_atomic
from common.keys import AliveKind
from common.leasemac import check_world_token, new_lease_key, seal_key
from common.messages import (
    AgentContextState,
    AgentEvent,
    CancelControl,
    ChatSay,
    ContextInfo,
    ContextInfoRequest,
    ContextSettings,
    ControllerOutput,
    ControlQueued,
    ControlRequest,
    ErrorReply,
    Lease,
    Message,
    MessageError,
    OkReply,
    OutputLines,
    QueueStateRequest,
    RequestStatus,
    Revocation,
    RunAccepted,
    RunClaim,
    RunRequest,
    RunStop,
    SessionToken,
    StopControl,
    UserRemovalRequest,
    WorldFrame,
    WorldSnapshot,
    decode,
)
from common.precheck import PrecheckError, precheck
from common.service import RequestError
from services.context.agent_queue import (
    ControlJob,
    QueueBook,
    RunningJob,
    load_book,
    new_request_id,
    save_book,
)
from services.context.chat_room import ChatRoom, log

LEASE_REPUBLISH_S = 1.0
SNAPSHOT_RETRY_S = 2.0
WORLD_IDENTITY_REFRESH_S = 5.0  # a restarted world has a new identity: reseal lease keys to it
MAX_WAITING_PER_USER = 4
RUNNER_GRACE_S = 1.5  # how long to wait before taking a runner's token loss as its death


class AgentContext(ChatRoom):
    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        name: str,
        *,
        world: str,
        runner: str = "runner",
        slot_seconds: float = 60.0,
        **room: Any,
    ) -> None:
        super().__init__(session, realm, name, **room)
        self.world = keys.check_ident("world", world)
        self.runner = keys.check_ident("runner", runner)
        self.book = QueueBook(slot_seconds)
        data_dir = room.get("data_dir")
        # Queues, settings and running slots survive a crash of this process: written
        # (atomically, synced) whenever they change, read back here.
        self._book_path: Path | None = None if data_dir is None else data_dir / f"{name}.queues"
        self._save_lock = threading.Lock()
        self._restore_book()
        self._wake = threading.Condition(self._lock)
        self._thread: threading.Thread | None = None
        self._halt = threading.Event()
        self._lease_pubs: dict[str, zenoh.Publisher] = {}
        self._end_reasons: dict[str, tuple[str, str]] = {}  # request id -> (status, reason)
        self._dirty = True
        self._layout: int | None = None
        self._frames: Any = None
        self._recent: dict[str, RunningJob] = {}  # runs that ended lately, for trailing output
        self._runner_users: dict[str, str] = {}  # request id -> the runner account driving it
        self._world_token: SessionToken | None = None  # verified; lease keys are sealed to it

    def _restore_book(self) -> None:
        if self._book_path is None or not self._book_path.exists():
            return
        try:
            self.book = load_book(self._book_path.read_bytes())
        except (OSError, ValueError) as exc:
            self.log.warning("could not restore the queues from %s: %s", self._book_path, exc)
            return
        waiting = sum(len(line.waiting) for line in self.book.lines.values())
        running = [line.running for line in self.book.lines.values() if line.running]
        self.log.info(
            "restored %d waiting and %d running requests (slots of %g s) from %s",
            waiting,
            len(running),
            self.book.slot_seconds,
            self._book_path,
        )

    def _save_book(self) -> None:
        if self._book_path is None:
            return
        with self._save_lock:  # one writer at a time, the newest state last
            with self._lock:
                data = save_book(self.book)
            try:
                write_atomic(self._book_path, data)
                os.chmod(self._book_path, 0o600)  # running slots carry their lease keys
            except OSError as exc:
                self.log.error("could not save the queues to %s: %s", self._book_path, exc)

    # -- lifecycle

    def on_start(self) -> None:
        super().on_start()
        self.subscribe(keys.ctx_output(self.realm, self.room), self._on_output)
        # A runner that dies takes its sandboxes with it: their students are told so.
        # The registry's token tells a runner's death from our own router blip (in a
        # blip every token goes at once, and the runner's sandboxes keep running).
        self._registry_gone_at = 0.0
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive(self.realm, AliveKind.RUNNER, self.runner), self._on_runner_presence
            )
        )
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive_of_kind(self.realm, AliveKind.REGISTRY), self._on_registry_presence
            )
        )
        self._frames = self.track(
            self.session.declare_subscriber(
                keys.world_frame(self.realm, self.world), zenoh.handlers.RingChannel(1)
            )
        )
        self._thread = threading.Thread(target=self._schedule, name="agent-queues", daemon=True)
        self._thread.start()

    def on_stop(self, timeout: float) -> None:
        self._halt.set()
        with self._wake:
            self._wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
        # Nobody keeps a robot after the context is gone: end every lease now.
        with self._lock:
            running = [line.running for line in self.book.lines.values() if line.running]
        for run in running:
            self._end_run(run, "cancelled", "the agent context stopped")
        with self._lock:
            for line in self.book.lines.values():
                line.running = None
        self._save_book()  # a clean stop ends the slots: they must not come back
        for pub in self._lease_pubs.values():
            pub.undeclare()
        super().on_stop(timeout)

    # -- manage rights

    def _manages(self, principal: Principal) -> bool:
        return principal.user == self.owner or principal.allowed(
            "kick", self.scope, restricted=self.restricted
        )

    def _require_manage(self, principal: Principal, what: str) -> None:
        if not self._manages(principal):
            raise AuthError(
                "forbidden",
                f"only the owner of {self.room} or a user with 'kick' there may {what}",
            )

    def _require_agent(self, agent: str) -> None:
        with self._lock:
            known = agent in self.book.lines
            names = ", ".join(sorted(self.book.lines)) or "none yet"
        if not known:
            raise RequestError(
                "not_found", f"no agent {agent} in world {self.world} (agents: {names})"
            )

    # -- requests

    def on_state(self, query: zenoh.Query) -> Message:
        self.verifier.open(str(query.key_expr), query.payload, ContextInfoRequest)
        return ContextInfo(
            ctx=self.room, kind="agent", owner=self.owner, title=self.title, members=self.members()
        )

    def on_request(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr),
            query.payload,
            (
                ChatSay,
                UserRemovalRequest,
                ControlRequest,
                CancelControl,
                StopControl,
                ContextSettings,
                QueueStateRequest,
            ),
        )
        if isinstance(request, ChatSay):
            self._say(principal, request)
            return OkReply()
        if isinstance(request, UserRemovalRequest):
            return self._kick(principal, request)
        if isinstance(request, QueueStateRequest):
            self._require(principal, "join", "see the queues")
            return self.state_message()
        reply: Message
        if isinstance(request, ControlRequest):
            reply = self._queue(principal, request)
        elif isinstance(request, CancelControl):
            reply = self._cancel(principal, request)
        elif isinstance(request, StopControl):
            reply = self._stop_agent(principal, request)
        else:
            reply = self._settings(principal, request)
        # On disk before the answer: an acknowledged request survives a crash right after.
        self._save_book()
        return reply

    def _queue(self, principal: Principal, request: ControlRequest) -> Message:
        self._require_member(principal)
        permission = "control" if request.mode == "remote" else "deploy"
        principal.require(
            permission,
            f"{'drive' if request.mode == 'remote' else 'deploy a controller on'} {request.agent}",
            scope=acl.agent_scope(self.room, request.agent),
            restricted=self.restricted,
        )
        self._require_agent(request.agent)
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
        with self._wake:
            if not self.book.can_run(request.agent):
                raise RequestError(
                    "forbidden",
                    f"remote control of {request.agent} is disabled in {self.room} for now",
                )
            mine = [j for j, _ in self.book.jobs_of_session(principal.session_id)]
            if any(j.agent == request.agent for j in mine):
                raise RequestError(
                    "conflict", f"you already have a request on {request.agent}: cancel it first"
                )
            waiting = sum(
                1
                for line in self.book.lines.values()
                for j in line.waiting
                if j.user == principal.user
            )
            if waiting >= MAX_WAITING_PER_USER:
                raise RequestError(
                    "rate_limited", f"at most {MAX_WAITING_PER_USER} waiting requests per user"
                )
            position = self.book.add(job)
            eta = self.book.eta(request.agent, position, now)
            self._dirty = True
            self._wake.notify_all()
        log.info("%s queued %s (%s) at %d", principal.user, job.request_id, job.mode, position)
        self._publish_agent(
            AgentEvent(ctx=self.room, request=self._status(job, "queued")),
        )
        return ControlQueued(
            request_id=job.request_id,
            agent=job.agent,
            position=position,
            start_eta=eta,
            slot_seconds=self.book.slot_seconds,
        )

    def _cancel(self, principal: Principal, request: CancelControl) -> Message:
        with self._wake:
            found = self.book.find(request.request_id)
            if found is None:
                raise RequestError("not_found", f"no request {request.request_id} in {self.room}")
            _, job, running = found
            if job.user != principal.user and not self._manages(principal):
                raise RequestError("forbidden", f"request {request.request_id} is not yours")
            if not running:
                self.book.remove_waiting(job.request_id)
                self._dirty = True
            else:
                self._finish_soon(job.request_id, "cancelled", f"cancelled by {principal.user}")
            self._wake.notify_all()
        if not running:
            self._publish_agent(
                AgentEvent(
                    ctx=self.room,
                    request=self._status(job, "cancelled", f"cancelled by {principal.user}"),
                )
            )
        return OkReply(detail=f"request {request.request_id} cancelled")

    def _stop_agent(self, principal: Principal, request: StopControl) -> Message:
        self._require_manage(principal, f"stop the controller on {request.agent}")
        self._require_agent(request.agent)
        with self._wake:
            run = self.book.lines[request.agent].running
            if run is None:
                return OkReply(detail=f"nothing runs on {request.agent}")
            why = f"stopped by {principal.user}" + (f": {request.reason}" if request.reason else "")
            self._finish_soon(run.job.request_id, "cancelled", why)
            self._wake.notify_all()
        return OkReply(detail=f"stopping {run.job.request_id}")

    def _settings(self, principal: Principal, request: ContextSettings) -> Message:
        self._require_manage(principal, "change the settings")
        if request.agent is not None:
            self._require_agent(request.agent)
        done: list[str] = []
        with self._wake:
            if request.slot_seconds is not None:
                self.book.slot_seconds = request.slot_seconds
                done.append(f"slots of {request.slot_seconds:g} s from the next one")
            if request.enabled is not None:
                if request.agent is not None:
                    self.book.lines[request.agent].enabled = request.enabled
                    lines = [self.book.lines[request.agent]]
                else:
                    self.book.enabled = request.enabled
                    lines = list(self.book.lines.values())
                where = request.agent or "every agent"
                done.append(f"remote control {'on' if request.enabled else 'off'} for {where}")
                if not request.enabled:
                    for line in lines:
                        if line.running is not None:
                            self._finish_soon(
                                line.running.job.request_id,
                                "cancelled",
                                f"remote control disabled by {principal.user}",
                            )
            self._dirty = True
            self._wake.notify_all()
        log.info("%s changed the settings: %s", principal.user, "; ".join(done))
        return OkReply(detail="; ".join(done) or "nothing changed")

    def _finish_soon(self, request_id: str, status: str, reason: str) -> None:
        """Make a running request end at the scheduler's next turn (lock held)."""
        found = self.book.find(request_id)
        if found is None or not found[2]:
            return
        line = found[0]
        assert line.running is not None
        self._end_reasons.setdefault(request_id, (status, reason))
        line.running.end = min(line.running.end, time.time())

    # -- members leaving: their requests go with them

    def _on_revoked(self, rev: Revocation) -> None:
        super()._on_revoked(rev)
        # Kicked, removed or logged out: the session's requests end, waiting or running
        # (the worlds drop its leases themselves, from the same revocation).
        why = "you were kicked from the server" if rev.kicked else "your session ended"
        self._drop_session_jobs(
            rev.session_id, f"{why}: {rev.reason}" if rev.reason else why, remote_only=False
        )

    def on_session_left(self, principal: Principal) -> None:
        self._drop_session_jobs(principal.session_id, "left the context", remote_only=False)

    def _drop_session_jobs(self, session_id: bytes, reason: str, *, remote_only: bool) -> None:
        cancelled: list[ControlJob] = []
        with self._wake:
            for job, running in self.book.jobs_of_session(session_id):
                if remote_only and job.mode != "remote":
                    continue
                if running:
                    self._finish_soon(job.request_id, "cancelled", reason)
                else:
                    self.book.remove_waiting(job.request_id)
                    cancelled.append(job)
            self._dirty = True
            self._wake.notify_all()
        for job in cancelled:
            self._publish_agent(
                AgentEvent(ctx=self.room, request=self._status(job, "cancelled", reason))
            )

    def _on_registry_presence(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE:
            self._registry_gone_at = time.monotonic()

    def _on_runner_presence(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        gone_at = time.monotonic()
        timer = threading.Timer(RUNNER_GRACE_S, self._runner_gone, args=(gone_at,))
        timer.daemon = True
        timer.start()

    def _runner_gone(self, gone_at: float) -> None:
        if abs(self._registry_gone_at - gone_at) < RUNNER_GRACE_S:
            self.log.info("runner %s and the registry went together: a router blip", self.runner)
            return
        with self._wake:
            ended = [
                line.running.job.request_id
                for line in self.book.lines.values()
                if line.running is not None and line.running.job.mode == "deploy"
            ]
            for request_id in ended:
                self._finish_soon(
                    request_id,
                    "cancelled",
                    f"the lab's runner {self.runner} stopped (crashed or restarted): your "
                    "controller was ended; upload it again",
                )
            self._wake.notify_all()
        if ended:
            self.log.warning("runner %s went away: ended %s", self.runner, ", ".join(ended))

    def _on_presence(self, sample: zenoh.Sample) -> None:
        super()._on_presence(sample)
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        parsed = keys.parse_alive(self.realm, str(sample.key_expr))
        if parsed is None:
            return
        with self._lock:
            sessions = {
                job.session_id
                for line in self.book.lines.values()
                for job in ([line.running.job] if line.running else []) + list(line.waiting)
                if job.user == parsed[1] and job.mode == "remote"
            }
        for session_id in sessions:
            self._drop_session_jobs(session_id, "the client went away", remote_only=True)

    # -- output from whoever drives

    def _on_output(self, sample: zenoh.Sample) -> None:
        principal, report = self.verifier.open(
            str(sample.key_expr), sample.payload, ControllerOutput
        )
        with self._wake:
            found = self.book.find(report.request_id)
            run = found[0].running if found is not None and found[2] else None
            # Lines can trail the end of a slot (the last prints, a traceback).
            run = run or self._recent.get(report.request_id)
            if run is None or run.holder_session != principal.session_id:
                raise AuthError(
                    "forbidden", f"{principal.user} does not drive request {report.request_id}"
                )
            if report.done:
                reason = report.reason or "the controller ended"
                self._finish_soon(report.request_id, "finished", reason)
                self._wake.notify_all()
        if report.lines:
            self._publish_agent(
                AgentEvent(
                    ctx=self.room,
                    output=OutputLines(
                        request_id=run.job.request_id,
                        agent=run.job.agent,
                        user=run.job.user,
                        lines=list(report.lines),
                    ),
                )
            )

    # -- events and state

    def state_message(self) -> AgentContextState:
        now = time.time()
        with self._lock:
            return AgentContextState(
                ctx=self.room,
                world=self.world,
                slot_seconds=self.book.slot_seconds,
                enabled=self.book.enabled,
                agents=self.book.agent_queues(now),
                at=now,
            )

    def _status(
        self, job: ControlJob, status: str, reason: str = "", run: RunningJob | None = None
    ) -> RequestStatus:
        return RequestStatus(
            request_id=job.request_id,
            agent=job.agent,
            user=job.user,
            status=status,  # type: ignore[arg-type]
            reason=reason,
            start=run.start if run else None,
            end=run.end if run else None,
        )

    def _publish_agent(self, event: AgentEvent) -> None:
        if self._publisher is None or (self.stopped and event.state is not None):
            return
        try:
            self._publisher.put(self.login.session.seal(self._events_key, event))
        except Exception as exc:  # the session closing at shutdown
            self.log.debug("could not publish an event: %s", exc)

    # -- the scheduler thread: agents, leases, starts and ends

    def _schedule(self) -> None:
        last_snapshot_try = 0.0
        last_republish = 0.0
        while not self._halt.is_set():
            try:
                now = time.time()
                if (
                    self._need_snapshot() and now - last_snapshot_try >= SNAPSHOT_RETRY_S
                ) or now - last_snapshot_try >= WORLD_IDENTITY_REFRESH_S:
                    last_snapshot_try = now
                    self._refresh_agents()
                self._turn()
                if time.monotonic() - last_republish >= LEASE_REPUBLISH_S:
                    last_republish = time.monotonic()
                    with self._lock:
                        running = [ln.running for ln in self.book.lines.values() if ln.running]
                    for run in running:
                        self._publish_lease(run, run.end)
                if self._dirty:
                    self._dirty = False
                    self._save_book()
                    self._publish_agent(AgentEvent(ctx=self.room, state=self.state_message()))
            except Exception:
                self.log.exception("error in the agent scheduler (kept running)")
            with self._wake:
                if not self._halt.is_set():
                    self._wake.wait(self._next_wait())

    def _next_wait(self) -> float:
        now = time.time()
        ends = [ln.running.end - now for ln in self.book.lines.values() if ln.running is not None]
        return max(0.01, min([0.25, *ends]))

    def _need_snapshot(self) -> bool:
        if self._layout is None:
            return True
        try:
            sample = self._frames.try_recv() if self._frames is not None else None
        except Exception:
            return False
        if sample is None:
            return False
        try:
            frame = decode(sample.payload, WorldFrame)
        except MessageError:
            return False
        return frame.layout != self._layout

    def _refresh_agents(self) -> None:
        try:
            replies = list(
                self.session.get(keys.world_snapshot(self.realm, self.world), timeout=3.0)
            )
        except Exception as exc:
            self.log.info("world %s snapshot: %s", self.world, exc)
            return
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                snap = decode(reply.ok.payload, (WorldSnapshot, ErrorReply))
            except MessageError as exc:
                self.log.warning("unreadable snapshot of %s: %s", self.world, exc)
                continue
            if not isinstance(snap, WorldSnapshot):
                continue
            self._note_world_identity(snap)
            with self._wake:
                first = self._layout is None
                self._layout = snap.layout
                gone = self.book.set_agents({a.id: a.type for a in snap.agents})
                for job in gone:
                    self._end_reasons.setdefault(
                        job.request_id, ("cancelled", f"{job.agent} left the world")
                    )
                self._dirty = True
            if first:
                self.log.info(
                    "world %s has agents %s", self.world, ", ".join(a.id for a in snap.agents)
                )
            for job in gone:
                self._publish_agent(
                    AgentEvent(
                        ctx=self.room,
                        request=self._status(job, "cancelled", f"{job.agent} left the world"),
                    )
                )
            return

    def _note_world_identity(self, snap: WorldSnapshot) -> None:
        """Keep the world's verified identity token, or none: lease keys are sealed only to it."""
        token: SessionToken | None = None
        if snap.identity is not None:
            try:
                token = check_world_token(self.verifier, snap.identity, self.world)
            except AuthError as exc:
                self.log.warning("world %s identity refused (no MAC leases): %s", self.world, exc)
        previous = self._world_token
        if token is not None and (previous is None or previous.box_key != token.box_key):
            self.log.info("world %s runs as %s: leases carry MAC keys", self.world, token.user)
        self._world_token = token

    def _turn(self) -> None:
        now = time.time()
        with self._lock:
            ended = self.book.expired(now)
            for run in ended:
                self.book.lines[run.job.agent].running = None
            starts = []
            for agent in list(self.book.lines):
                job = self.book.next_to_start(agent)
                if job is not None:
                    starts.append(job)
            if ended or starts:
                self._dirty = True
        for run in ended:
            with self._lock:
                self._recent[run.job.request_id] = run
                while len(self._recent) > 64:
                    self._recent.pop(next(iter(self._recent)))
            self._runner_users.pop(run.job.request_id, None)
            status, reason = self._end_reasons.pop(
                run.job.request_id, ("finished", "its slot ended")
            )
            self._end_run(run, status, reason)
        for job in starts:
            self._start(job)

    def _end_run(self, run: RunningJob, status: str, reason: str) -> None:
        # The same lease id, ending now, replaces the lease in the world at once.
        self._publish_lease(run, min(run.end, time.time()))
        if run.job.mode == "deploy":
            self._ask_runner(RunStop(request_id=run.job.request_id, reason=reason), timeout=2.0)
        log.info("%s %s on %s: %s", run.job.request_id, status, run.job.agent, reason)
        self._publish_agent(
            AgentEvent(ctx=self.room, request=self._status(run.job, status, reason))
        )

    def _start(self, job: ControlJob) -> None:
        start = time.time()
        end = start + self.book.slot_seconds
        holder, holder_box = job.session_id, job.box_key
        if job.mode == "deploy":
            try:
                holder, holder_box = self._start_on_runner(job, end)
            except RequestError as exc:
                log.warning("%s refused: %s", job.request_id, exc.message)
                self._publish_agent(
                    AgentEvent(ctx=self.room, request=self._status(job, "refused", exc.message))
                )
                with self._wake:
                    self._dirty = True
                    self._wake.notify_all()
                return
        run = RunningJob(
            job=job,
            lease_id=f"{self.room}.{job.request_id}"[:64],
            holder_session=holder,
            start=start,
            end=end,
            holder_box=holder_box,
            lease_key=new_lease_key(),
        )
        with self._lock:
            line = self.book.lines.get(job.agent)
            if line is None or line.running is not None:
                return
            line.running = run
            self._dirty = True
        self._publish_lease(run, end)
        log.info("%s runs on %s for %s until %.1f", job.request_id, job.agent, job.user, end)
        self._publish_agent(
            AgentEvent(ctx=self.room, request=self._status(job, "running", run=run))
        )

    def _publish_lease(self, run: RunningJob, end: float) -> None:
        agent = run.job.agent
        key = keys.agent_lease(self.realm, self.world, agent)
        pub = self._lease_pubs.get(agent)
        if pub is None:
            pub = self._lease_pubs[agent] = self.session.declare_publisher(key)
        lease = Lease(
            lease_id=run.lease_id,
            world=self.world,
            agent=agent,
            holder_user=run.job.user if run.job.mode == "remote" else self.runner_user(run),
            holder_session=run.holder_session,
            start=run.start,
            end=end,
        )
        sealed = self._lease_keys(run)
        if sealed is not None:
            lease = msgspec.structs.replace(
                lease, holder_key=sealed[0], world_key=sealed[1], world_box=sealed[2]
            )
        try:
            pub.put(self.login.session.seal(key, lease))
        except Exception as exc:
            self.log.warning("could not publish the lease of %s: %s", agent, exc)

    def _lease_keys(self, run: RunningJob) -> tuple[bytes, bytes, bytes] | None:
        """The MAC lease fields: K sealed to the holder and to the world's verified identity.

        (holder's copy, world's copy, the world box key sealed to); None when
        the world has no (valid, unexpired) identity: the holder then
        signs its commands, as every world understands.
        """
        world = self._world_token
        if world is None or world.expires_at <= time.time() or len(run.holder_box) != 32:
            return None
        cache = (run.holder_box, world.box_key)
        sealed = run.sealed.get(cache)
        if sealed is None:
            sealed = (
                seal_key(run.lease_key, run.holder_box),
                seal_key(run.lease_key, world.box_key),
            )
            run.sealed[cache] = sealed
        return sealed[0], sealed[1], world.box_key

    def runner_user(self, run: RunningJob) -> str:
        return self._runner_users.get(run.job.request_id, run.job.user)

    # -- the runner

    def _ask_runner(self, message: Message, timeout: float) -> Message | None:
        key = keys.runner_run(self.realm, self.runner)
        try:
            replies = list(
                self.session.get(
                    key, payload=self.login.session.seal(key, message), timeout=timeout
                )
            )
        except Exception as exc:
            self.log.warning("runner %s: %s", self.runner, exc)
            return None
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return decode(reply.ok.payload, (RunAccepted, OkReply, ErrorReply))
            except MessageError as exc:
                self.log.warning("unreadable runner reply: %s", exc)
        return None

    def _start_on_runner(self, job: ControlJob, end: float) -> tuple[bytes, bytes]:
        """The runner's session id and box key, once it accepted to run ``job``."""
        key = keys.runner_run(self.realm, self.runner)
        reply = self._ask_runner(
            RunRequest(
                request_id=job.request_id,
                ctx=self.room,
                world=self.world,
                agent=job.agent,
                user=job.user,
                source=job.source,
                end=end,
                filename=job.filename,
            ),
            timeout=10.0,
        )
        if reply is None:
            raise RequestError("unavailable", f"no runner {self.runner} answered")
        if isinstance(reply, ErrorReply):
            raise RequestError("unavailable", f"runner: {reply.message}")
        if not isinstance(reply, RunAccepted):
            raise RequestError("unavailable", "runner gave an unexpected reply")
        try:
            principal, claim = self.verifier.open(key, reply.claim, RunClaim)
        except (AuthError, MessageError) as exc:
            raise RequestError("unavailable", f"runner's claim refused: {exc}") from None
        if not principal.has("run") or claim.request_id != job.request_id:
            raise RequestError("unavailable", f"{principal.user} may not run controllers")
        self._runner_users[job.request_id] = principal.user
        return principal.session_id, principal.token.box_key
