"""What the viewer needs from the lab, as small Protocols.

The viewer's UI is written against these, never against Zenoh or the wire
messages directly. The demo lab implements them in memory
(viewers/web/demo_lab.py), the live lab over the registry client (``LabClient``,
viewers/web/live.py). Everything else here is plain data (frozen dataclasses).
A world, as the page draws it, has its own module: viewers/web/world_feed.py.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Protocol

from common import lab_errors
from common.client.lab_address import LabAddress
from common.client.survey import Survey
from common.lab_errors import LabError
from common.messages.agent import MAX_UPLOAD_BYTES
from common.messages.audit import AuditEntry, AuditQuery
from common.messages.grading import (
    AssignmentInfo,
    ClassTable,
    GradingChanged,
    Leaderboard,
    Standings,
    SubmissionInfo,
)
from common.twin.twinfile import Twin
from viewers.web.world_feed import WorldFeed

# --- errors ---------------------------------------------------------------------

# LabError is the lab's one (common/lab_errors.py, imported above for the page's
# modules): a refused or failed request, whose str() is shown to the person as is.
# The page raises it in its own words too; plain_error words the registry client's.


class LoginError(LabError):
    """Wrong user or password, no such lab, registry not answering."""


class LoginUnavailable(LoginError):
    """The lab could not take the login now (its registry down or busy): nothing was
    refused, and a saved login stays good for the next try."""


def plain_error(exc: LabError, address: LabAddress | None = None) -> LabError:
    """A lab client's error in the words the page shows; ``address``, the lab whose
    registry was asked, is named when that registry does not answer."""
    if isinstance(exc, lab_errors.RegistryUnreachable) and address is not None:
        return LabError(f"the lab at {address.label} does not answer (is its registry running?)")
    if isinstance(exc, lab_errors.NotAllowed):
        return LabError(f"not allowed: {exc}")
    if isinstance(exc, lab_errors.NotLoggedIn):
        return LabError("your session with this lab has ended: log in again")
    if isinstance(exc, lab_errors.RateLimited):
        return LabError(f"too many requests: try again in {exc.retry_after:.0f} s")
    return LabError(str(exc))


# --- lab: directory, contexts, chat ------------------------------------------------


@dataclass(frozen=True)
class ContextSummary:
    """A live context as the lobby lists it."""

    ctx: str
    kind: str  # "chat" or "agent" (an arena)
    owner: str
    title: str = ""
    members: int = 0
    world: str | None = None  # the world an agent context is bound to


@dataclass(frozen=True)
class Directory:
    server_name: str
    users: tuple[str, ...]
    contexts: tuple[ContextSummary, ...]


@dataclass(frozen=True)
class ChatEntry:
    seq: int
    sender: str
    text: str
    at: float


@dataclass(frozen=True)
class JoinedContext:
    """What a join returns: enough to draw the context's tab."""

    ctx: str
    kind: str
    title: str
    owner: str
    members: tuple[str, ...]
    history: tuple[ChatEntry, ...]
    world: str | None = None
    can_kick: bool = False


# Events arrive on the lab connection's own threads; the viewer only updates
# GUI handles from them (cheap, non-blocking), never waits on the network.


@dataclass(frozen=True)
class ChatEvent:
    ctx: str
    line: ChatEntry


@dataclass(frozen=True)
class MemberEvent:
    ctx: str
    user: str
    status: Literal["joined", "left", "kicked"]
    members: tuple[str, ...]
    by: str | None = None
    reason: str = ""


@dataclass(frozen=True)
class PrivateEvent:
    sender: str
    text: str
    at: float


@dataclass(frozen=True)
class DirectoryEvent:
    """The directory changed (someone came or went, a context opened or closed)."""


@dataclass(frozen=True)
class DisconnectedEvent:
    """The session ended from the other side (kicked from the server, lab gone)."""

    reason: str


@dataclass(frozen=True)
class AgentsEvent:
    """An arena's agents or queues changed."""

    ctx: str


@dataclass(frozen=True)
class RequestEvent:
    """A controller request changed state (queued, running, finished, cancelled, refused)."""

    ctx: str
    request_id: str
    agent: str
    user: str
    status: str
    reason: str = ""
    takeover: str | None = None  # running, a teacher's take-over: "taken" or "handed_back"


@dataclass(frozen=True)
class OutputEvent:
    """Lines a running controller printed (its prints and tracebacks)."""

    ctx: str
    request_id: str
    agent: str
    user: str
    lines: tuple[str, ...]
    first: int = 0  # how many lines the run printed before these (the context's count)


@dataclass(frozen=True)
class OutputSoFar:
    """A run's last output lines as its context kept them; ``first`` counts those before."""

    first: int
    lines: tuple[str, ...]


LabEvent = (
    ChatEvent
    | MemberEvent
    | PrivateEvent
    | DirectoryEvent
    | DisconnectedEvent
    | AgentsEvent
    | RequestEvent
    | OutputEvent
)

# --- agents, queues, controllers --------------------------------------------------


@dataclass(frozen=True)
class AgentStatus:
    """One robot of an arena, as the robot panel lists it."""

    agent: str
    holder: str | None  # who controls it now
    queue: int  # how many wait for it
    my_position: int | None = None  # 0 = mine runs now, 1 = next; None = I am not queued
    eta_s: float | None = None  # until my slot starts (None: now, or the agent is disabled)
    enabled: bool = True  # remote control allowed (the context and this agent)
    online: bool = True  # a real robot unplugged or silent is offline
    my_request: str | None = None  # my request's id on this agent
    slot_left_s: float | None = None  # what remains of the running slot
    taken_by: str | None = None  # a teacher who took the running controller's robot over
    waiting: tuple[str, ...] = ()  # who waits for it, in order


@dataclass(frozen=True)
class Queued:
    """Where a request waits: 0 runs now, 1 next; ``eta_s`` until its slot (None: disabled)."""

    request_id: str
    agent: str
    position: int
    eta_s: float | None
    slot_seconds: float


@dataclass(frozen=True)
class ArenaSettings:
    """An agent context's settings as the robot panel shows them."""

    slot_seconds: float
    enabled: bool
    can_manage: bool  # the owner or 'kick' there: slot length, stop, enable/disable, estop
    estop: str = ""  # "emergency stop by <who>: why" while the host holds every robot


@dataclass(frozen=True)
class DryRunResult:
    """A dry run's report as the page shows it: the verdict first, then what it saw."""

    will_run: bool
    verdict: str  # "will run" / "will NOT run: line 12: ..."
    details: tuple[str, ...] = ()  # collisions, saturated wheels, printed lines
    line: int | None = None  # the controller file's line an exception came from


@dataclass(frozen=True)
class SavedFile:
    """One of my controller files, as the agent context keeps it for the editor."""

    name: str
    size: int
    saved_at: float  # wall-clock seconds


@dataclass(frozen=True)
class RecordingEntry:
    """One of my recorded runs in an arena, as the Recordings folder lists it."""

    name: str  # the run's request id (what a download asks for)
    agent: str
    start: float  # wall-clock seconds
    size: int  # bytes of the MCAP file
    status: str = ""  # how it ended (finished, cancelled, ...); "" when not summarised
    reason: str = ""
    duration_s: float | None = None
    distance_mm: float | None = None


# One figure for the page's check and the agent context's limit (the wire type's bound).
MAX_CONTROLLER_BYTES = MAX_UPLOAD_BYTES
CONTROLLER_SUFFIXES = (".py",)


@dataclass(frozen=True)
class Account:
    """One account as the admin panel lists it."""

    name: str
    roles: tuple[str, ...]
    grants: tuple[tuple[str, tuple[str, ...]], ...]  # (scope, grants there); "" = everywhere
    online: bool = False
    failed_logins: int = 0  # since the registry started or the last unlock
    banned: str = ""  # the ban in force, in words ("" if none)


class CourseCalls(Protocol):
    """A connection's courses: the grader's calls and feeds (docs/COURSES.md)."""

    def assignments(self) -> list[AssignmentInfo]:
        """The assignments of my courses."""
        ...

    def submit(self, assignment: str, filename: str, source: bytes) -> str:
        """Hand the file in to ``assignment``; what the grader said, in words."""
        ...

    def submissions(self, assignment: str) -> list[SubmissionInfo]:
        """My submissions to ``assignment``, oldest first, with their scores."""
        ...

    def leaderboard(self, assignment: str) -> Leaderboard: ...

    def fetch_episode(self, assignment: str, submission: str, episode: int, dest: Path) -> Path:
        """Download a graded episode's recording of mine into ``dest``; returns ``dest``."""
        ...

    def watch_standings(self, on_standings: Callable[[Standings], None]) -> Callable[[], None]:
        """Competitions' standings as the grader publishes them; returns: stop watching."""
        ...

    def watch_grading(self, on_change: Callable[[GradingChanged], None]) -> Callable[[], None]:
        """Submissions changing state (any course; no score in it); returns: stop watching."""
        ...

    def class_tables(self) -> list[ClassTable]:
        """The teacher's view of each course I teach (none for a student)."""
        ...


class AdminCalls(Protocol):
    """A connection's account administration; each raises LabError without the permission."""

    def list_accounts(self) -> list[Account]: ...

    def add_account(self, user: str, password: str, roles: tuple[str, ...]) -> str: ...

    def set_password(self, user: str, password: str, current: str | None = None) -> str: ...

    def remove_account(self, user: str) -> str: ...

    def grant(self, user: str, grant: str, scope: str = "") -> str: ...

    def ungrant(self, user: str, grant: str, scope: str = "") -> str: ...

    def kick_from_server(self, user: str, reason: str = "") -> str: ...

    def rename_server(self, name: str) -> str: ...

    def unlock_logins(self, user: str) -> str: ...

    def ban(self, user: str, reason: str, until: float | None) -> str: ...

    def lift_ban(self, user: str) -> str: ...

    def audit_trail(self, query: AuditQuery) -> list[AuditEntry]: ...


class LabConnection(Protocol):
    """One logged-in user's session with one lab (the viewer holds one per tab group)."""

    @property
    def address(self) -> LabAddress: ...

    @property
    def user(self) -> str: ...

    @property
    def permissions(self) -> frozenset[str]: ...

    def directory(self) -> Directory: ...

    def check_resume(self) -> None:
        """LabError in the lab's words if this session's saved login is no longer good;
        LoginUnavailable if the lab could not say now (its registry down or busy)."""
        ...

    def join(self, ctx: str) -> JoinedContext: ...

    def leave(self, ctx: str) -> None: ...

    def say(self, ctx: str, text: str) -> None: ...

    def kick(self, ctx: str, user: str, reason: str = "") -> None: ...

    def host(self, kind: Literal["chat", "agent"], name: str, map_name: str = "") -> str:
        """Open a new context; returns its id."""
        ...

    def survey(self) -> Survey:
        """The lab's routers, live services and hosts, with findings (admins)."""
        ...

    def send_private(self, to: str, text: str) -> None: ...

    def subscribe(self, callback: Callable[[LabEvent], None]) -> Callable[[], None]:
        """Call ``callback`` for every event from now on; returns the unsubscriber."""
        ...

    def world(self, world: str) -> WorldFeed: ...

    def agents(self, ctx: str) -> list[AgentStatus]: ...

    def request_control(self, ctx: str, agent: str, filename: str, source: bytes) -> Queued:
        """Queue an uploaded controller on ``agent``; :class:`LabError` says why not."""
        ...

    def cancel_control(self, ctx: str, agent: str) -> str:
        """Cancel my request on ``agent`` (waiting or running); returns what the context said."""
        ...

    def arena_settings(self, ctx: str) -> ArenaSettings: ...

    def set_slot(self, ctx: str, seconds: float) -> str: ...

    def stop_agent(self, ctx: str, agent: str) -> str: ...

    def take_over(self, ctx: str, agent: str, take: bool) -> str:
        """Take ``agent`` over from its running controller (``take``), or hand it back."""
        ...

    def drive(self, ctx: str, agent: str, left: int, right: int) -> None:
        """Wheel speeds for a robot I took over, held until changed (0, 0: stop)."""
        ...

    def set_enabled(self, ctx: str, enabled: bool, agent: str | None = None) -> str: ...

    # -- the editor (workbench): my files in the arena's context, reset, the real arenas

    def list_files(self, ctx: str) -> list[SavedFile]:
        """My own files kept by ``ctx``, newest first."""
        ...

    def read_file(self, ctx: str, name: str) -> bytes: ...

    def save_file(self, ctx: str, name: str, source: bytes) -> str: ...

    def reset_robot(self, ctx: str, agent: str) -> str:
        """Put ``agent`` back at its start pose (a simulated arena, while I hold it)."""
        ...

    def real_robots(self) -> list[tuple[str, str]]:
        """(context, agent) of every robot of the real arenas I have joined."""

    def emergency_stop(self, ctx: str, engaged: bool, reason: str = "") -> str:
        """Stop every robot of the arena and hold it (``engaged``), or release it."""
        ...

    def dry_run(self, ctx: str, agent: str, filename: str, source: bytes) -> DryRunResult:
        """A few simulated seconds of the file in a private copy of the arena; queues nothing."""
        ...

    # -- my recordings (every slot an agent context runs is recorded: common/recording/)

    def output_so_far(self, ctx: str, request_id: str) -> OutputSoFar:
        """The run's last output lines, for a page that comes to it late (LabError: none)."""
        ...

    def recordings(self, ctx: str) -> list[RecordingEntry]:
        """My recorded runs in ``ctx``, newest first."""
        ...

    def fetch_recording(self, ctx: str, name: str, dest: Path) -> Path:
        """Download recording ``name`` of ``ctx`` into the file ``dest``; returns ``dest``."""
        ...

    def promote(self, ctx: str, agent: str, recording: Path) -> Queued:
        """Queue the controller file of a recorded (deploy) run on ``agent`` of ``ctx``."""
        ...

    def save_twin(self, ctx: str, robot: str, document: str) -> str:
        """Have the registry keep a twin file's text as ``robot``'s twin, for the arena
        ``ctx`` the user owns; the answer in words (LabError: refused, and why)."""
        ...

    def twin(self, ctx: str, robot: str) -> Twin | None:
        """The twin in force of arena ``ctx``'s ``robot``, read with my session (None: none
        kept); LabError when the registry refuses me (students read no twins) or does not
        answer."""
        ...

    @property
    def courses(self) -> CourseCalls:
        """My courses (the grader: docs/COURSES.md) through this connection."""
        ...

    def logout(self, keep_resume: bool = False, reason: str = "") -> None:
        """Log out; ``keep_resume`` (the page closed, not "Log out") keeps its saved login.

        ``reason``: why, as the rooms left tell those whose runs end with it.
        """
        ...

    def hand_over(self) -> None:
        """The viewer stops: let the session go as a crash would, not logged out.

        No room is left and the session and its saved login stay good: its page logs
        in again on the next viewer, and its runs in simulation go on meanwhile.
        """
        ...

    @property
    def resume_token(self) -> bytes | None:
        """The registry's token to come back without a password (None: none was given)."""
        ...

    @property
    def admin(self) -> AdminCalls:
        """The account administration calls (thesis 9.2.1) of this connection."""
        ...


class LabConnector(Protocol):
    """Opens lab connections; :class:`LoginError` with plain words when it cannot."""

    def login(
        self, address: LabAddress, user: str, password: str, via: str = "", seen_from: str = ""
    ) -> LabConnection:
        """Log in; ``via`` names the browser connection (logged by the registry);
        ``seen_from`` is the browser's address as this viewer's socket saw it, which
        the viewer vouches for (the registry throttles failed logins per address)."""
        ...

    def resume(
        self, address: LabAddress, token: bytes, via: str = "", seen_from: str = ""
    ) -> LabConnection:
        """Log in again with a saved login's resume token; LoginError in the lab's words."""
        ...
