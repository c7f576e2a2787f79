"""The demo lab: in-memory labs and worlds behind the viewer's Protocols.

Used by the phase-1 tests, ``wart viewer --demo`` and bench/bench_viewer.py.
They behave like the real services in the ways the UI relies on: logins can
fail, several connections share one lab (so two browsers chat), events arrive
on other threads, a world produces frames at its own rate on its own thread.
"""

from __future__ import annotations

import itertools
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from common.client.lab_address import LabAddress
from common.client.survey import RouterView, Survey
from common.keys import is_ident
from common.messages.grading import (
    AssignmentInfo,
    ClassTable,
    GradingChanged,
    Leaderboard,
    Standings,
    SubmissionInfo,
)
from common.recording import RecordingError, read_recording, summarize
from common.twin.twinfile import Twin
from viewers.web import demo_world
from viewers.web.adapters import (
    AgentsEvent,
    AgentStatus,
    ArenaSettings,
    ChatEntry,
    ChatEvent,
    ContextSummary,
    Directory,
    DirectoryEvent,
    DryRunResult,
    JoinedContext,
    LabError,
    LabEvent,
    LoginError,
    MemberEvent,
    OutputSoFar,
    PrivateEvent,
    Queued,
    RecordingEntry,
    SavedFile,
)
from viewers.web.demo_admin import ADMIN, INSTRUCTOR, STUDENT, DemoAdmin
from viewers.web.live_agents import check_upload

# The demo world, in a module of its own; still importable from here, as the
# tests and benches do.
DemoWorld = demo_world.DemoWorld


@dataclass
class _Context:
    summary: ContextSummary
    members: list[str] = field(default_factory=list)
    history: list[ChatEntry] = field(default_factory=list)
    queue: dict[str, list[str]] = field(default_factory=dict)  # agent -> users waiting
    slot_seconds: float = 60.0
    enabled: bool = True
    estop: str = ""


class DemoLab:
    """One lab shared by all its connections: accounts, contexts, chat, worlds."""

    def __init__(self, server_name: str = "Fake lab", *, robots: int = 8, rate: float = 50.0):
        self.server_name = server_name
        self.accounts: dict[str, tuple[str, frozenset[str]]] = {
            "ana": ("ana-pw", INSTRUCTOR),
            "ben": ("ben-pw", STUDENT),
            "root": ("root-pw", ADMIN),
        }
        self.worlds: dict[str, DemoWorld] = {"arena": DemoWorld("arena", robots, rate=rate)}
        self._lock = threading.RLock()
        self.files: dict[str, dict[str, tuple[bytes, float]]] = {}  # user -> name -> (src, at)
        # ctx -> its recordings (the demo records nothing itself: tests and demos add files)
        self.recordings: dict[str, dict[str, tuple[Path, RecordingEntry, str]]] = {}
        self._contexts: dict[str, _Context] = {}
        self._online: dict[str, int] = {}
        self._subs: dict[int, tuple[str, Callable[[LabEvent], None]]] = {}
        self._ids = itertools.count(1)
        self._seq = itertools.count(1)
        self._open("lobby", "chat", "ana", "Lobby chat")
        self._open("arena", "agent", "ana", "Simulated arena", world="arena")

    def add_recording(self, ctx: str, path: Path) -> RecordingEntry:
        """Offer the recording ``path`` in ``ctx`` to the user who ran it (its RunInfo.user)."""
        rec = read_recording(path)
        summary = summarize(rec)
        entry = RecordingEntry(
            name=summary.request_id,
            agent=summary.agent,
            start=summary.start,
            size=path.stat().st_size,
            status=summary.status,
            reason=summary.reason,
            duration_s=summary.duration_s,
            distance_mm=summary.distance_mm,
        )
        with self._lock:
            self.recordings.setdefault(ctx, {})[entry.name] = (path, entry, summary.user)
        return entry

    def close(self) -> None:
        for world in self.worlds.values():
            world.stop()

    def _open(self, ctx: str, kind: str, owner: str, title: str, world: str | None = None) -> None:
        summary = ContextSummary(ctx, kind, owner, title, 0, world)
        context = _Context(summary)
        if world is not None:
            context.queue = {name: [] for name in self.worlds[world].snapshot().robots[:8]}
        self._contexts[ctx] = context

    # -- what connections call

    def login(self, address: LabAddress, user: str, password: str) -> DemoConnection:
        account = self.accounts.get(user)
        if account is None or account[0] != password:
            raise LoginError("wrong user name or password")
        with self._lock:
            self._online[user] = self._online.get(user, 0) + 1
        self._broadcast(DirectoryEvent())
        return DemoConnection(self, address.with_user(user), user, account[1])

    def _broadcast(self, event: LabEvent, only: set[str] | None = None) -> None:
        with self._lock:
            targets = [cb for user, cb in self._subs.values() if only is None or user in only]
        for callback in targets:  # outside the lock: a callback may call back in
            callback(event)

    def directory(self) -> Directory:
        with self._lock:
            contexts = tuple(
                replace(c.summary, members=len(c.members)) for c in self._contexts.values()
            )
            return Directory(self.server_name, tuple(sorted(self._online)), contexts)

    def context(self, ctx: str) -> _Context:
        context = self._contexts.get(ctx)
        if context is None:
            raise LabError(f"there is no context {ctx!r} (any more)")
        return context

    def next_seq(self) -> int:
        return next(self._seq)


class DemoConnector:
    """A :class:`~viewers.web.adapters.LabConnector` over one or more fake labs, found by
    realm; an unknown realm fails the way an unreachable lab would."""

    def __init__(self, *labs: tuple[str, DemoLab]) -> None:
        self.labs = dict(labs)

    def login(
        self, address: LabAddress, user: str, password: str, via: str = "", seen_from: str = ""
    ) -> DemoConnection:
        lab = self.labs.get(address.realm)
        if lab is None:
            raise LoginError(f"no lab answers at {address.label}: check the address")
        return lab.login(address, user, password)

    def resume(
        self, address: LabAddress, token: bytes, via: str = "", seen_from: str = ""
    ) -> DemoConnection:
        raise LoginError("this lab keeps no saved logins: log in with your password")


class DemoCourses:
    """The demo lab's courses: none, for it has no grader (a real lab's is `wart grader`)."""

    def assignments(self) -> list[AssignmentInfo]:
        return []

    def submit(self, assignment: str, filename: str, source: bytes) -> str:
        raise LabError("the demo lab grades nothing: no grader runs here")

    def submissions(self, assignment: str) -> list[SubmissionInfo]:
        return []

    def leaderboard(self, assignment: str) -> Leaderboard:
        raise LabError("the demo lab has no leaderboards: no grader runs here")

    def fetch_episode(self, assignment: str, submission: str, episode: int, dest: Path) -> Path:
        raise LabError("the demo lab grades nothing: no episode to replay")

    def watch_standings(self, on_standings: Callable[[Standings], None]) -> Callable[[], None]:
        return lambda: None  # no grader: no competition

    def watch_grading(self, on_change: Callable[[GradingChanged], None]) -> Callable[[], None]:
        return lambda: None  # no grader: nothing changes

    def class_tables(self) -> list[ClassTable]:
        return []  # no grader: no class


class DemoConnection:
    """One user's session with a :class:`DemoLab`."""

    def __init__(self, lab: DemoLab, address: LabAddress, user: str, perms: frozenset[str]):
        self._lab = lab
        self._address = address
        self._user = user
        self._perms = perms
        self._sub_ids: list[int] = []
        self._joined: set[str] = set()
        self.uploads: list[tuple[str, str, str, int]] = []  # ctx, agent, filename, size
        self.closed = False
        self._admin = DemoAdmin(lab, user, self._need)

    @property
    def admin(self) -> DemoAdmin:
        return self._admin

    @property
    def courses(self) -> DemoCourses:
        return DemoCourses()

    @property
    def address(self) -> LabAddress:
        return self._address

    @property
    def user(self) -> str:
        return self._user

    @property
    def permissions(self) -> frozenset[str]:
        return self._perms

    def _need(self, permission: str, doing: str) -> None:
        if self.closed:
            raise LabError("you are logged out of this lab")
        if permission not in self._perms:
            raise LabError(f"you may not {doing} (no '{permission}' permission)")

    def directory(self) -> Directory:
        return self._lab.directory()

    def check_resume(self) -> None:
        raise LabError("a demo lab keeps no saved logins")

    def join(self, ctx: str) -> JoinedContext:
        self._need("join", "join contexts")
        lab = self._lab
        with lab._lock:
            context = lab.context(ctx)
            if self._user not in context.members:
                context.members.append(self._user)
            members = tuple(context.members)
            self._joined.add(ctx)
            joined = JoinedContext(
                ctx=ctx,
                kind=context.summary.kind,
                title=context.summary.title,
                owner=context.summary.owner,
                members=members,
                history=tuple(context.history[-50:]),
                world=context.summary.world,
                can_kick="kick" in self._perms or context.summary.owner == self._user,
            )
        lab._broadcast(MemberEvent(ctx, self._user, "joined", members))
        lab._broadcast(DirectoryEvent())
        return joined

    def leave(self, ctx: str) -> None:
        self._remove(ctx, self._user, "left")

    def _remove(self, ctx: str, user: str, status: Literal["left", "kicked"], by: str = "") -> None:
        lab = self._lab
        with lab._lock:
            context = lab.context(ctx)
            if user not in context.members:
                return
            context.members.remove(user)
            members = tuple(context.members)
        lab._broadcast(MemberEvent(ctx, user, status, members, by or None))
        lab._broadcast(DirectoryEvent())

    def say(self, ctx: str, text: str) -> None:
        self._need("chat", "chat")
        lab = self._lab
        with lab._lock:
            context = lab.context(ctx)
            if self._user not in context.members:
                raise LabError(f"join {ctx} before writing there")
            line = ChatEntry(lab.next_seq(), self._user, text, time.time())
            context.history.append(line)
            members = set(context.members)
        lab._broadcast(ChatEvent(ctx, line), only=members)

    def kick(self, ctx: str, user: str, reason: str = "") -> None:
        context = self._lab.context(ctx)
        if "kick" not in self._perms and context.summary.owner != self._user:
            raise LabError("you may not kick people from this context")
        if user == self._user:
            raise LabError("you cannot kick yourself; use Leave")
        self._remove(ctx, user, "kicked", by=self._user)

    def survey(self) -> Survey:
        self._need("admin", "survey the lab's network")
        with self._lab._lock:
            contexts = sorted(self._lab._contexts)
        return Survey(
            realm="demo",
            routers=[RouterView("demo-router", "0" * 32, 0.1, [], 1)],
            alive={"context": contexts, "registry": ["registry"]},
            hosts=[],
        )

    def host(self, kind: Literal["chat", "agent"], name: str, map_name: str = "") -> str:
        self._need("host", "open new contexts")
        if not is_ident(name):
            raise LabError(f"{name!r} is not a valid name: letters, digits, '_', '-', '.'")
        lab = self._lab
        with lab._lock:
            if name in lab._contexts:
                raise LabError(f"a context named {name!r} already exists")
            world = None
            if kind == "agent":
                world = name
                lab.worlds[name] = DemoWorld(name, 4)
            lab._open(name, kind, self._user, map_name or name, world)
        lab._broadcast(DirectoryEvent())
        return name

    def send_private(self, to: str, text: str) -> None:
        self._need("chat", "send messages")
        self._lab._broadcast(PrivateEvent(self._user, text, time.time()), only={to})

    def subscribe(self, callback: Callable[[LabEvent], None]) -> Callable[[], None]:
        lab = self._lab
        with lab._lock:
            sub_id = next(lab._ids)
            lab._subs[sub_id] = (self._user, callback)
        self._sub_ids.append(sub_id)

        def unsubscribe() -> None:
            with lab._lock:
                lab._subs.pop(sub_id, None)

        return unsubscribe

    def world(self, world: str) -> DemoWorld:
        feed = self._lab.worlds.get(world)
        if feed is None:
            raise LabError(f"there is no world {world!r}")
        return feed

    def agents(self, ctx: str) -> list[AgentStatus]:
        with self._lab._lock:
            context = self._lab.context(ctx)
            out = []
            for agent, waiting in context.queue.items():
                holder = waiting[0] if waiting else None
                mine = waiting.index(self._user) if self._user in waiting else None
                out.append(
                    AgentStatus(
                        agent=agent,
                        holder=holder,
                        queue=max(0, len(waiting) - 1),
                        my_position=mine,
                        eta_s=None if mine is None else context.slot_seconds * mine,
                        enabled=context.enabled,
                    )
                )
            return out

    def request_control(self, ctx: str, agent: str, filename: str, source: bytes) -> Queued:
        self._need("deploy", "upload controllers")
        with self._lab._lock:
            context = self._lab.context(ctx)
            queue = context.queue.get(agent)
            if queue is None:
                raise LabError(f"there is no robot {agent!r} in {ctx}")
            if not context.enabled:
                raise LabError(f"remote control is disabled in {ctx} for now")
            if self._user in queue:
                raise LabError(f"you already have a request on {agent}: cancel it first")
            queue.append(self._user)
            position = queue.index(self._user)
            self.uploads.append((ctx, agent, filename, len(source)))
        self._lab._broadcast(AgentsEvent(ctx))
        slot = context.slot_seconds
        return Queued(f"{agent}-{len(self.uploads)}", agent, position, slot * position, slot)

    def cancel_control(self, ctx: str, agent: str) -> str:
        with self._lab._lock:
            queue = self._lab.context(ctx).queue.get(agent, [])
            if self._user not in queue:
                raise LabError(f"you have no request on {agent}")
            queue.remove(self._user)
        self._lab._broadcast(AgentsEvent(ctx))
        return f"your request on {agent} is cancelled"

    def arena_settings(self, ctx: str) -> ArenaSettings:
        with self._lab._lock:
            context = self._lab.context(ctx)
            manage = context.summary.owner == self._user or "kick" in self._perms
            return ArenaSettings(context.slot_seconds, context.enabled, manage, context.estop)

    def _manage(self, ctx: str) -> _Context:
        context = self._lab.context(ctx)
        if context.summary.owner != self._user and "kick" not in self._perms:
            raise LabError(f"only the owner of {ctx} or a user with 'kick' there may do that")
        return context

    def set_slot(self, ctx: str, seconds: float) -> str:
        with self._lab._lock:
            self._manage(ctx).slot_seconds = seconds
        self._lab._broadcast(AgentsEvent(ctx))
        return f"slots of {seconds:g} s from the next one"

    def stop_agent(self, ctx: str, agent: str) -> str:
        with self._lab._lock:
            queue = self._manage(ctx).queue.get(agent, [])
            who = queue.pop(0) if queue else None
        self._lab._broadcast(AgentsEvent(ctx))
        return f"stopped {who}'s controller" if who else f"nothing runs on {agent}"

    def _no_take_over(self, *_: object) -> Any:
        raise LabError("the demo lab runs no one's controller: nothing to take over")

    take_over = drive = _no_take_over

    def set_enabled(self, ctx: str, enabled: bool, agent: str | None = None) -> str:
        with self._lab._lock:
            self._manage(ctx).enabled = enabled
        self._lab._broadcast(AgentsEvent(ctx))
        return f"remote control {'on' if enabled else 'off'}"

    # -- the editor: files per user in the lab (not per connection), like the real context

    def list_files(self, ctx: str) -> list[SavedFile]:
        with self._lab._lock:
            self._lab.context(ctx)
            mine = self._lab.files.get(self._user, {})
            rows = [SavedFile(n, len(src), t) for n, (src, t) in mine.items()]
        return sorted(rows, key=lambda f: -f.saved_at)

    def read_file(self, ctx: str, name: str) -> bytes:
        with self._lab._lock:
            kept = self._lab.files.get(self._user, {}).get(name)
        if kept is None:
            raise LabError(f"you have no file named {name}")
        return kept[0]

    def save_file(self, ctx: str, name: str, source: bytes) -> str:
        if not name.endswith(".py") or not is_ident(name):
            raise LabError(f"{name!r} is not a file name")
        with self._lab._lock:
            self._lab.context(ctx)
            mine = self._lab.files.setdefault(self._user, {})
            mine[name] = (source, time.time())
            for old in sorted(mine, key=lambda n: mine[n][1])[: max(0, len(mine) - 10)]:
                del mine[old]
        return f"saved {name} ({len(source)} bytes)"

    def reset_robot(self, ctx: str, agent: str) -> str:
        with self._lab._lock:
            queue = self._lab.context(ctx).queue.get(agent)
            if queue is None:
                raise LabError(f"there is no robot {agent!r} in {ctx}")
            if not queue or queue[0] != self._user:
                raise LabError(f"{agent} is not yours now: reset it while your controller holds it")
        return f"{agent} is back at its start"  # demo robots circle their home spots anyway

    def real_robots(self) -> list[tuple[str, str]]:
        return []  # the demo lab has no real arena

    def emergency_stop(self, ctx: str, engaged: bool, reason: str = "") -> str:
        with self._lab._lock:
            context = self._manage(ctx)
            context.estop = f"emergency stop by {self._user}" if engaged else ""
            ended = 0
            if engaged:  # the fake runs nothing: the head of each queue is what "runs"
                for queue in context.queue.values():
                    ended += bool(queue)
                    del queue[:1]
        self._lab._broadcast(AgentsEvent(ctx))
        if engaged:
            plural = "" if ended == 1 else "s"
            return f"emergency stop: every robot stopped, {ended} controller{plural} ended"
        return "emergency stop released"

    def dry_run(self, ctx: str, agent: str, filename: str, source: bytes) -> DryRunResult:
        self._need("deploy", "dry-run controllers")
        problem = check_upload(filename, source)[1]
        if problem:
            raise LabError(problem)
        with self._lab._lock:
            if agent not in self._lab.context(ctx).queue:
                raise LabError(f"there is no robot {agent!r} in {ctx}")
        # The fake lab has no sandbox: it runs nothing and says so.
        return DryRunResult(True, "will run (demo lab: the file was checked, not run)")

    def output_so_far(self, ctx: str, request_id: str) -> OutputSoFar:
        return OutputSoFar(0, ())  # the demo's runs print nothing

    # -- recordings

    def recordings(self, ctx: str) -> list[RecordingEntry]:
        with self._lab._lock:
            self._lab.context(ctx)
            kept = list(self._lab.recordings.get(ctx, {}).values())
        mine = [entry for _, entry, user in kept if user == self._user]
        return sorted(mine, key=lambda r: r.start, reverse=True)

    def fetch_recording(self, ctx: str, name: str, dest: Path) -> Path:
        with self._lab._lock:
            kept = self._lab.recordings.get(ctx, {}).get(name)
        if kept is None or kept[2] != self._user:
            raise LabError(f"you have no recording named {name} in {ctx}")
        shutil.copyfile(kept[0], dest)
        return dest

    def promote(self, ctx: str, agent: str, recording: Path) -> Queued:
        try:
            rec = read_recording(recording)
        except RecordingError as exc:
            raise LabError(str(exc)) from None
        info = rec.info
        if info is None or info.mode != "deploy" or rec.source is None:
            raise LabError("this run's recording holds no controller file to promote")
        return self.request_control(ctx, agent, info.filename or "controller.py", rec.source)

    def save_twin(self, ctx: str, robot: str, document: str) -> str:
        raise LabError("the demo lab has no real robots: it keeps no twins")

    def twin(self, ctx: str, robot: str) -> Twin | None:
        return None  # no real robots, no twins

    resume_token: bytes | None = None  # a demo lab keeps no saved logins

    def logout(self, keep_resume: bool = False, reason: str = "") -> None:
        if self.closed:
            return
        for ctx in list(self._joined):
            self._remove(ctx, self._user, "left")
        lab = self._lab
        with lab._lock:
            for sub_id in self._sub_ids:
                lab._subs.pop(sub_id, None)
            left = lab._online.get(self._user, 1) - 1
            if left <= 0:
                lab._online.pop(self._user, None)
            else:
                lab._online[self._user] = left
        self.closed = True
        lab._broadcast(DirectoryEvent())

    def hand_over(self) -> None:
        self.logout()  # nothing outlives the demo lab's viewer: it is in the same process
