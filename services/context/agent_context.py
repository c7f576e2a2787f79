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

MAC leases (common/world/leasemac.py): when the world's snapshot carries an
identity token the registry signed with the ``world`` permission, each lease
also carries a fresh per-lease key sealed to the holder and to that world,
so the holder's commands are MACed (µs to check) rather than signed.

Rights (registry ACL, scopes ``ctx/<ctx>`` and ``agent/<ctx>/<agent>``):
``join``; ``control`` (remote) or ``deploy`` (upload) on the agent; the
owner, or ``kick`` in the context, *manages*: slot length, stop, enable or
disable remote control for the context or one agent, cancel anyone's request.

The queues and the runs in flight are one
:class:`~services.context.context_state.ContextState`, shared by the parts
wired here: the queue desk (queue_requests.py: queue, cancel, stop, settings,
the emergency stop, dry runs), the slot scheduler (slots.py: its thread) and
the take-over desk (takeover.py). Members, chat and rights are the chat room's;
this class routes requests, follows presence and output, and saves the queues.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any, cast

import zenoh

from common import keys
from common.auth import AuthError, Principal
from common.files import write_atomic
from common.keys import AliveKind
from common.messages import (
    AgentContextState,
    AgentEvent,
    CancelControl,
    ChatSay,
    ContextInfo,
    ContextInfoRequest,
    ContextSettings,
    ControllerOutput,
    ControlRequest,
    EmergencyStop,
    FileListRequest,
    HandBack,
    Message,
    OkReply,
    OutputLines,
    OutputSoFar,
    OutputSoFarRequest,
    QueueStateRequest,
    ReadFile,
    RecordingGet,
    RecordingListRequest,
    RequestStatus,
    Revocation,
    SaveFile,
    StopControl,
    TakeOver,
    UserRemovalRequest,
)
from common.messages.chat import ChatLine, MemberStatus
from common.recording.store import RecordingStore
from common.service import RequestError
from services.context.agent_queue import (
    QueueBook,
    RunningJob,
    load_book,
    save_book,
)
from services.context.chat_room import ChatRoom
from services.context.context_state import ContextState
from services.context.lease_signer import LeaseSigner
from services.context.output_tail import OutputTails
from services.context.queue_requests import QueueDesk
from services.context.recorder import SlotRecorder
from services.context.recordings import RecordingRequests
from services.context.request_status import RequestStatusDesk
from services.context.runner_link import RunnerLink
from services.context.slots import SlotScheduler
from services.context.takeover import TakeOverDesk
from services.context.user_files import UserFiles

DRY_RUN_WORKERS = 2
DRY_RUN_WAITING = 4
RUNNER_GRACE_S = 1.5  # after a runner's token went, before asking it what it still runs
RUNNER_CHECK_S = 15.0  # how long to keep asking before taking its silence for its death


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
        recordings: RecordingStore | None = None,
        **room: Any,
    ) -> None:
        super().__init__(session, realm, name, **room)
        self.world = keys.check_ident("world", world)
        self.runner = keys.check_ident("runner", runner)
        data_dir = room.get("data_dir")
        # Queues, settings and running slots survive a crash of this process: written
        # (atomically, synced) whenever they change, read back here.
        self._book_path: Path | None = None if data_dir is None else data_dir / f"{name}.queues"
        self._save_lock = threading.Lock()
        self.state = ContextState(name, self.world, self._restore_book(QueueBook(slot_seconds)))
        # The page's editor keeps each member's last files here, beside the queues.
        self.files = UserFiles(None if data_dir is None else data_dir / f"{name}.files")
        self.outputs = OutputTails()  # each run's last lines, for a page that comes late
        self.leases = LeaseSigner(session, realm, self.world, self._seal, self.verifier, self.log)
        self.runner_link = RunnerLink(
            session, realm, self.runner, self._seal, self.verifier, self.log
        )
        self.status_desk = RequestStatusDesk(
            name, self.owner, self.verifier, self.state.look_up, restricted=self.restricted
        )
        self.recorder = SlotRecorder(
            session, realm, name, self.world, recordings, self.registry_key, self.log
        )
        self.recordings = RecordingRequests(recordings, name)
        # Its parts, on the one state they share: each is handed what it uses.
        self.queue_desk = QueueDesk(
            self.state,
            session=session,
            realm=realm,
            restricted=self.restricted,
            verifier=self.verifier,
            seal=self._seal,
            runner_link=self.runner_link,
            require_member=self._require_member,
            require_manage=self._require_manage,
            manages=self._manages,
            publish=self._publish_agent,
            log=self.log,
        )
        self.scheduler = SlotScheduler(
            self.state,
            session=session,
            realm=realm,
            leases=self.leases,
            runner_link=self.runner_link,
            recorder=self.recorder,
            save=self._save_book,
            publish=self._publish_agent,
            publish_world_stop=self.queue_desk.publish_world_stop,
            log=self.log,
        )
        self.takeovers = TakeOverDesk(
            self.state,
            leases=self.leases,
            audit=self.audit,
            require_manage=self._require_manage,
            publish=self._publish_agent,
            publish_lease=self.scheduler.publish_lease,
        )

    def _seal(self, key: str, message: Message) -> bytes:
        """Sealed with the context's current session (renewed sessions included)."""
        return self.login.session.seal(key, message)

    def _restore_book(self, empty: QueueBook) -> QueueBook:
        """The queues saved before a crash, or ``empty`` if there are none to read."""
        if self._book_path is None or not self._book_path.exists():
            return empty
        try:
            book = load_book(self._book_path.read_bytes())
        except (OSError, ValueError) as exc:
            self.log.warning("could not restore the queues from %s: %s", self._book_path, exc)
            return empty
        waiting = sum(len(line.waiting) for line in book.lines.values())
        running = [line.running for line in book.lines.values() if line.running]
        self.log.info(
            "restored %d waiting and %d running requests (slots of %g s) from %s",
            waiting,
            len(running),
            book.slot_seconds,
            self._book_path,
        )
        return book

    def _save_book(self) -> None:
        if self._book_path is None:
            return
        with self._save_lock:  # one writer at a time, the newest state last
            with self.state.lock:
                data = save_book(self.state.book)
            try:
                # running slots carry their lease keys: never readable by another account
                write_atomic(self._book_path, data, mode=0o600)
            except OSError as exc:
                self.log.error("could not save the queues to %s: %s", self._book_path, exc)

    # -- lifecycle

    def on_start(self) -> None:
        super().on_start()
        self.subscribe(keys.ctx_output(self.realm, self.room), self._on_output)
        # Its own key: a client asking how its request ended is never behind an upload.
        self.serve(
            keys.ctx_status(self.realm, self.room),
            lambda query: self.status_desk.answer(str(query.key_expr), query.payload),
        )
        # Dry runs take seconds: their own key and threads, so queueing, stops and
        # the emergency stop are never behind one.
        self.serve(
            keys.ctx_dryrun(self.realm, self.room),
            self.queue_desk.on_dry_run,
            workers=DRY_RUN_WORKERS,
            max_waiting=DRY_RUN_WAITING,
        )
        # A runner that dies takes its sandboxes with it: their students are told so.
        # Its token going is not enough to say it died (a router blip takes every
        # token away for a moment, while the sandboxes run on): the runner is asked
        # what it still runs (_check_runner).
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive(self.realm, AliveKind.RUNNER, self.runner), self._on_runner_presence
            )
        )
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive(self.realm, AliveKind.WORLD, self.world),
                self.scheduler.on_world_presence,
            )
        )
        # The world's layout news, not its frames: a world whose frames nobody reads
        # (no page watching, no slot recorded) builds none.
        self.track(
            self.session.declare_subscriber(
                keys.world_layout(self.realm, self.world), self.scheduler.on_world_layout
            )
        )
        self.recorder.start()
        self.scheduler.start()

    def on_stop(self, timeout: float) -> None:
        self.scheduler.stop(timeout)
        self._save_book()  # a clean stop ends the slots: they must not come back
        self.recorder.close(timeout)
        self.leases.close()
        super().on_stop(timeout)

    # -- manage rights

    def _manages(self, principal: Principal) -> bool:
        return self._allowed(principal, "kick")

    def _require_manage(self, principal: Principal, what: str) -> None:
        if not self._manages(principal):
            raise AuthError(
                "forbidden",
                f"only the owner of {self.room} or a user with 'kick' there may {what}",
            )

    # -- requests

    def on_state(self, query: zenoh.Query) -> Message:
        self.verifier.open(str(query.key_expr), query.payload, ContextInfoRequest)
        with self.state.lock:
            robots = sorted(self.state.book.lines)
        return ContextInfo(
            ctx=self.room,
            kind="agent",
            owner=self.owner,
            title=self.title,
            members=self.members(),
            robots=robots,
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
                OutputSoFarRequest,
                RecordingListRequest,
                RecordingGet,
                SaveFile,
                FileListRequest,
                ReadFile,
                EmergencyStop,
                TakeOver,
                HandBack,
            ),
        )
        if isinstance(request, SaveFile | FileListRequest | ReadFile):
            self._require_member(principal)
            return self.files.answer(principal.user, request)
        if isinstance(request, ChatSay):
            self._say(principal, request)
            return OkReply()
        if isinstance(request, UserRemovalRequest):
            where = f"{self.scope}/{request.user}"
            with self.audit.action(principal, "kick", where, request.reason):
                return self._kick(principal, request)
        if isinstance(request, QueueStateRequest):
            self._require(principal, "join", "see the queues")
            return self.state_message()
        if isinstance(request, OutputSoFarRequest):
            # Whoever may join sees every run's output in the events already.
            self._require(principal, "join", "see a run's output")
            return self._output_so_far(request.request_id)
        if isinstance(request, RecordingListRequest | RecordingGet):
            self._require(principal, "join", "see recordings")
            return self.recordings.answer(principal, request, self._manages(principal))
        reply: Message
        if isinstance(request, ControlRequest):
            reply = self.queue_desk.queue(principal, request)
        elif isinstance(request, CancelControl):
            reply = self.queue_desk.cancel(principal, request)
        elif isinstance(request, StopControl):
            where = f"agent/{self.room}/{request.agent}"
            with self.audit.action(principal, "stop_run", where, request.reason):
                reply = self.queue_desk.stop_agent(principal, request)
        elif isinstance(request, TakeOver):
            where = f"agent/{self.room}/{request.agent}"
            with self.audit.action(principal, "takeover", where, request.reason):
                reply = self.takeovers.take_over(principal, request)
        elif isinstance(request, HandBack):
            where = f"agent/{self.room}/{request.agent}"
            with self.audit.action(principal, "handback", where, ""):
                reply = self.takeovers.hand_back(principal, request)
        elif isinstance(request, EmergencyStop):
            action = "estop" if request.engaged else "release"
            with self.audit.action(principal, action, self.scope, request.reason):
                reply = self.queue_desk.emergency_stop(principal, request)
        else:  # the one kind left (open's overloads type a tuple this long as Message)
            settings = cast(ContextSettings, request)
            with self.audit.action(principal, "settings", self.scope, _said(settings)):
                reply = self.queue_desk.change_settings(principal, settings)
        # On disk before the answer: an acknowledged request survives a crash right after.
        self._save_book()
        return reply

    # -- members leaving: their requests go with them

    def _on_revoked(self, rev: Revocation) -> None:
        super()._on_revoked(rev)
        # Kicked, removed or logged out: the session's requests end, waiting or running
        # (the worlds drop its leases themselves, from the same revocation).
        why = "you were kicked from the server" if rev.kicked else "your session ended"
        self._drop_session_jobs(
            rev.session_id, f"{why}: {rev.reason}" if rev.reason else why, remote_only=False
        )

    def on_session_left(self, principal: Principal, reason: str = "") -> None:
        self._drop_session_jobs(
            principal.session_id, reason or "left the context", remote_only=False
        )

    def _drop_session_jobs(self, session_id: bytes, reason: str, *, remote_only: bool) -> None:
        # A teacher gone (left, vanished, revoked) gives back what they took over.
        self.takeovers.hand_back_session(session_id, f"went away ({reason})")
        cancelled: list[RequestStatus] = []
        with self.state.wake:
            for job, running in self.state.book.jobs_of_session(session_id):
                if remote_only and job.mode != "remote":
                    continue
                if running:
                    self.state.finish_soon(job.request_id, "cancelled", reason)
                else:
                    self.state.book.remove_waiting(job.request_id)
                    cancelled.append(self.state.ended(job, "cancelled", reason))
            self.state.dirty = True
            self.state.wake.notify_all()
        for final in cancelled:
            self._publish_agent(AgentEvent(ctx=self.room, request=final))

    def _on_runner_presence(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        # Our own router gone (a client session's tokens all vanish when its link
        # drops): a blip on our side, not the runner's death; its sandboxes run on.
        try:
            if not list(self.session.info.routers_zid()):
                self.log.info("runner %s out of sight with our router: a router blip", self.runner)
                return
        except Exception as exc:  # the session closing at shutdown
            self.log.debug("could not ask the session for its routers: %s", exc)
            return
        threading.Thread(
            target=self._check_runner, name=f"check-runner-{self.runner}", daemon=True
        ).start()

    def _deploys_running(self) -> list[str]:
        with self.state.wake:
            return [
                line.running.job.request_id
                for line in self.state.book.lines.values()
                if line.running is not None and line.running.job.mode == "deploy"
            ]

    def _check_runner(self) -> None:
        """After the runner's token went: end the runs it no longer has, once it says so.

        A runner cut off by a router blip (its token gone from our router's view,
        perhaps only while it or we reconnect) still runs its sandboxes, and says
        so when asked. One that crashed and was restarted runs none of them; one
        that is dead does not answer. Asked until RUNNER_CHECK_S has passed: the
        token alone misled here, when our session reconnected before the runner's
        (a false "runner stopped" in the chaos test, about one run in three).
        """
        if self.state.halt.wait(RUNNER_GRACE_S):
            return
        deadline = time.monotonic() + RUNNER_CHECK_S
        while not self.stopped:
            asked = self._deploys_running()
            if not asked:
                return
            running = self.runner_link.still_running(asked, timeout=2.0)
            if running is not None:
                ended = [r for r in asked if r not in running]
                if not ended:
                    self.log.info(
                        "runner %s answers and still runs %s: it was a blip",
                        self.runner,
                        ", ".join(asked),
                    )
                    return
                why = "it came back without them"
                break
            if time.monotonic() > deadline:
                ended = asked
                why = f"it has not answered for {RUNNER_CHECK_S:.0f} s"
                break
            if self.state.halt.wait(1.0):
                return
        else:
            return
        with self.state.wake:
            for request_id in ended:
                self.state.finish_soon(
                    request_id,
                    "cancelled",
                    f"the lab's runner {self.runner} stopped (crashed or restarted): your "
                    "controller was ended; upload it again",
                )
            self.state.wake.notify_all()
        self.log.warning("runner %s went away (%s): ended %s", self.runner, why, ", ".join(ended))

    def _on_presence(self, sample: zenoh.Sample) -> None:
        super()._on_presence(sample)
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        parsed = keys.parse_alive(self.realm, str(sample.key_expr))
        if parsed is None:
            return
        with self.state.lock:
            sessions = {
                job.session_id
                for line in self.state.book.lines.values()
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
        with self.state.wake:
            found = self.state.book.find(report.request_id)
            run = found[0].running if found is not None and found[2] else None
            # Lines can trail the end of a slot (the last prints, a traceback).
            run = run or self.state.recent.get(report.request_id)
            if run is None or run.holder_session != principal.session_id:
                raise AuthError(
                    "forbidden", f"{principal.user} does not drive request {report.request_id}"
                )
            if report.done:
                reason = report.reason or "the controller ended"
                self.state.finish_soon(report.request_id, "finished", reason)
                self.state.wake.notify_all()
        if report.lines:
            job = run.job
            self.recorder.output(job.request_id, job.agent, list(report.lines))
            first = self.outputs.add(job.request_id, job.agent, job.user, report.lines)
            self._publish_agent(
                AgentEvent(
                    ctx=self.room,
                    output=OutputLines(
                        request_id=job.request_id,
                        agent=job.agent,
                        user=job.user,
                        lines=list(report.lines),
                        first=first,
                    ),
                )
            )

    def _output_so_far(self, request_id: str) -> OutputSoFar:
        kept = self.outputs.so_far(request_id)
        if kept is not None:
            return kept
        known = self.state.look_up(request_id).status
        if known is None:
            raise RequestError(
                "not_found", f"no request {request_id} here (never queued, or long ago)"
            )
        return OutputSoFar(request_id=request_id, agent=known.agent, user=known.user)

    # -- events and state

    def state_message(self) -> AgentContextState:
        return self.state.state_message()

    def publish_world_stop(self, engaged: bool | None, by: str) -> None:
        self.queue_desk.publish_world_stop(engaged, by)

    def runner_user(self, run: RunningJob) -> str:
        return self.scheduler.runner_user(run)

    def _publish(self, *, line: ChatLine | None = None, status: MemberStatus | None = None) -> None:
        super()._publish(line=line, status=status)
        self.recorder.chat(line, status)  # said during a run: in its recording

    def _publish_agent(self, event: AgentEvent) -> None:
        if event.output is None:
            self.recorder.event(event)  # output is recorded where it comes in
        if self._publisher is None or (self.stopped and event.state is not None):
            return
        try:
            self._publisher.put(self.login.session.seal(self._events_key, event))
        except Exception as exc:  # the session closing at shutdown
            self.log.debug("could not publish an event: %s", exc)


def _said(request: ContextSettings) -> str:
    """A settings change in words, for its audit line (slot length, remote control)."""
    parts = []
    if request.slot_seconds is not None:
        parts.append(f"slot {request.slot_seconds:g} s")
    if request.enabled is not None:
        where = f" on {request.agent}" if request.agent else ""
        parts.append(f"remote control {'on' if request.enabled else 'off'}{where}")
    return ", ".join(parts)
