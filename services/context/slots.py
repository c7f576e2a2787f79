"""The scheduler thread of an agent context: the world's agents, slots that start and end.

Every quarter second (sooner when a slot ends) it ends the slots whose time
is up, starts the head of each free agent's queue (asking the runner first
for a deployed controller), republishes the leases in force every second,
re-reads the world's agents when the world says its layout changed (and its identity every
few seconds: a restarted world has a new one), and saves the queues when
anything changed. It shares the context's
:class:`~services.context.context_state.ContextState` with the queue desk and
the take-over desk, under its lock.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from common import keys
from common.ask import WrongReply, ask
from common.lab_errors import LabError
from common.messages import (
    AgentEvent,
    MessageError,
    RequestStatus,
    WorldLayout,
    WorldSnapshot,
    decode,
)
from common.service import RequestError
from common.world.leasemac import new_lease_key
from services.context.agent_queue import ControlJob, RunningJob
from services.context.context_state import ContextState, request_status
from services.context.lease_signer import LeaseSigner
from services.context.recorder import SlotRecorder
from services.context.runner_link import RunnerLink

log = logging.getLogger("wart.chat")  # the context's own logger (chat_room.py)

LEASE_REPUBLISH_S = 1.0
SNAPSHOT_RETRY_S = 2.0
WORLD_IDENTITY_REFRESH_S = 5.0  # a restarted world has a new identity: reseal lease keys to it


class SlotScheduler:
    """Slots of one world's agents, on the state the context's parts share."""

    def __init__(
        self,
        state: ContextState,
        *,
        session: zenoh.Session,
        realm: str,
        leases: LeaseSigner,
        runner_link: RunnerLink,
        recorder: SlotRecorder,
        save: Callable[[], None],
        publish: Callable[[AgentEvent], None],
        publish_world_stop: Callable[[bool | None, str], None],
        log: logging.Logger,
    ) -> None:
        """``save`` writes the queues to disk; ``publish`` tells the members an event
        (and records it); ``publish_world_stop`` tells the world the stop in force."""
        self.state = state
        self.session = session
        self.realm = realm
        self.leases = leases
        self.runner_link = runner_link
        self.recorder = recorder
        self.save = save
        self.publish = publish
        self.publish_world_stop = publish_world_stop
        self.log = log
        self._layout: int | None = None  # the world's, as last read from its snapshot
        self._announced: int | None = None  # the world's, as its last WorldLayout said
        self._world_appeared = False
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Run the scheduler thread."""
        self._thread = threading.Thread(target=self._schedule, name="agent-queues", daemon=True)
        self._thread.start()

    def stop(self, timeout: float) -> None:
        """End the thread, then every slot: nobody keeps a robot after the context is gone."""
        self.state.halt.set()
        with self.state.wake:
            self.state.wake.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
        for run in self.state.running():
            final = self.state.ended(run.job, "cancelled", "the agent context stopped", run)
            self.end_run(run, final)
        with self.state.lock:
            for line in self.state.book.lines.values():
                line.running = None

    def _schedule(self) -> None:
        last_snapshot_try = 0.0
        last_republish = 0.0
        while not self.state.halt.is_set():
            try:
                now = time.time()
                with self.state.wake:
                    appeared, self._world_appeared = self._world_appeared, False
                if (
                    appeared
                    or (self._need_snapshot() and now - last_snapshot_try >= SNAPSHOT_RETRY_S)
                    or now - last_snapshot_try >= WORLD_IDENTITY_REFRESH_S
                ):
                    last_snapshot_try = now
                    self._refresh_agents()
                self._turn()
                if time.monotonic() - last_republish >= LEASE_REPUBLISH_S:
                    last_republish = time.monotonic()
                    for run in self.state.running():
                        self.publish_lease(run, run.end)
                    # A restarted world learns a held stop as it relearns leases.
                    self.publish_world_stop(None, self.state.room)
                if self.state.dirty:
                    self.state.dirty = False
                    self.save()
                    self.publish(AgentEvent(ctx=self.state.room, state=self.state.state_message()))
            except Exception:
                self.log.exception("error in the agent scheduler (kept running)")
            with self.state.wake:
                if not self.state.halt.is_set():
                    self.state.wake.wait(self._next_wait())

    def _next_wait(self) -> float:
        now = time.time()
        lines = self.state.book.lines.values()
        ends = [ln.running.end - now for ln in lines if ln.running is not None]
        return max(0.01, min([0.25, *ends]))

    def on_world_presence(self, sample: zenoh.Sample) -> None:
        # The world came online (first start, a restart, or started after this
        # context): learn its agents now, not at the next retry. Started
        # together, a context queried before its world existed and refused
        # queues for up to SNAPSHOT_RETRY_S after the world was up.
        if sample.kind == zenoh.SampleKind.PUT:
            with self.state.wake:
                self._world_appeared = True
                self.state.wake.notify_all()

    def on_world_layout(self, sample: zenoh.Sample) -> None:
        """The world's rows changed (``world/<w>/layout``): learn them at the next turn."""
        try:
            news = decode(sample.payload, WorldLayout)
        except MessageError as exc:
            self.log.debug("unreadable layout news of %s: %s", self.state.world, exc)
            return
        if news.world != self.state.world:
            return
        with self.state.wake:
            self._announced = news.layout
            self.state.wake.notify_all()

    def _need_snapshot(self) -> bool:
        with self.state.wake:
            announced = self._announced
        return self._layout is None or (announced is not None and announced != self._layout)

    def _refresh_agents(self) -> None:
        world = self.state.world
        with self.state.wake:
            self._announced = None  # news from now on is newer than the snapshot asked
        key = keys.world_snapshot(self.realm, world)
        try:
            snap = ask(self.session, key, None, WorldSnapshot, what=f"world {world}", timeout=3.0)
        except WrongReply as exc:
            self.log.warning("unreadable snapshot of %s: %s", world, exc)
            return
        except LabError as exc:
            self.log.info("world %s snapshot: %s", world, exc)
            return
        self.leases.note_world_identity(snap.identity)
        self.recorder.world_snapshot(snap)
        with self.state.wake:
            first = self._layout is None
            self._layout = snap.layout
            gone = self.state.book.set_agents({a.id: a.type for a in snap.agents})
            finals = [
                self.state.ended(job, "cancelled", f"{job.agent} left the world") for job in gone
            ]
            self.state.dirty = True
        if first:
            self.log.info("world %s has agents %s", world, ", ".join(a.id for a in snap.agents))
        for final in finals:
            self.publish(AgentEvent(ctx=self.state.room, request=final))

    def _turn(self) -> None:
        now = time.time()
        with self.state.lock:
            ended = self.state.book.expired(now)
            finals = []
            for run in ended:
                self.state.book.lines[run.job.agent].running = None
                # Recorded as it leaves the queues, under the same lock: a client asking
                # in between finds it either running or ended, never unknown.
                status, reason = self.state.end_reasons.pop(
                    run.job.request_id, ("finished", "its slot ended")
                )
                finals.append(self.state.ended(run.job, status, reason, run))
                self.state.remember_ended_run(run)
            starts = []
            for agent in list(self.state.book.lines):
                job = self.state.book.next_to_start(agent)
                if job is not None:
                    starts.append(job)
                    self.state.starting[job.request_id] = job  # off its queue, not yet running
            if ended or starts:
                self.state.dirty = True
        for run, final in zip(ended, finals, strict=True):
            self.runner_link.forget(run.job.request_id)
            self.end_run(run, final)
        for job in starts:
            try:
                self._start(job)
            finally:
                with self.state.lock:
                    self.state.starting.pop(job.request_id, None)

    def end_run(self, run: RunningJob, final: RequestStatus) -> None:
        """Tell the world, the runner, the recording and the members that ``run`` ended
        (``final``: its last status, already recorded with :meth:`ContextState.ended`)."""
        # The same lease id, ending now, replaces the lease in the world at once.
        self.publish_lease(run, min(run.end, time.time()))
        if run.job.mode == "deploy":
            self.runner_link.stop(run.job.request_id, final.reason)
        log.info("%s %s on %s: %s", run.job.request_id, final.status, run.job.agent, final.reason)
        self.recorder.run_ended(run.job.request_id, final.status, final.reason)
        self.publish(AgentEvent(ctx=self.state.room, request=final))

    def _start(self, job: ControlJob) -> None:
        start = time.time()
        end = start + self.state.book.slot_seconds
        holder, holder_box = job.session_id, job.box_key
        if job.mode == "deploy":
            try:
                holder, holder_box = self.runner_link.start(
                    job, self.state.room, self.state.world, end
                )
            except RequestError as exc:
                log.warning("%s refused: %s", job.request_id, exc.message)
                with self.state.wake:
                    refused = self.state.ended(job, "refused", exc.message)
                    self.state.starting.pop(job.request_id, None)
                    self.state.dirty = True
                    self.state.wake.notify_all()
                self.publish(AgentEvent(ctx=self.state.room, request=refused))
                return
        run = RunningJob(
            job=job,
            lease_id=f"{self.state.room}.{job.request_id}"[:64],
            holder_session=holder,
            start=start,
            end=end,
            holder_box=holder_box,
            lease_key=new_lease_key(),
        )
        with self.state.lock:
            line = self.state.book.lines.get(job.agent)
            final: RequestStatus | None = None
            if line is None:  # the agent left the world while its slot was being set up
                final = self.state.ended(job, "cancelled", f"{job.agent} left the world")
            elif line.running is not None:  # only this thread starts slots: never seen
                self.log.error("%s: %s already runs something", job.request_id, job.agent)
                final = self.state.ended(job, "cancelled", f"{job.agent} was taken: queue again")
            else:
                line.running = run
            self.state.starting.pop(job.request_id, None)
            self.state.dirty = True
        if final is not None:
            if job.mode == "deploy":
                self.runner_link.stop(job.request_id, final.reason)
            self.publish(AgentEvent(ctx=self.state.room, request=final))
            return
        driver = job.user if job.mode == "remote" else self.runner_user(run)
        self.recorder.run_started(run, driver)  # before the lease: the first commands count
        self.publish_lease(run, end)
        log.info("%s runs on %s for %s until %.1f", job.request_id, job.agent, job.user, end)
        self.publish(
            AgentEvent(ctx=self.state.room, request=request_status(job, "running", run=run))
        )

    def publish_lease(self, run: RunningJob, end: float) -> None:
        taken = run.taken
        if taken is not None:  # taken over: the teacher's lease is the one in force
            self.leases.publish(taken, end, taken.job.user)
            return
        holder = run.job.user if run.job.mode == "remote" else self.runner_user(run)
        self.leases.publish(run, end, holder)

    def runner_user(self, run: RunningJob) -> str:
        return self.runner_link.driver(run.job.request_id, run.job.user)
