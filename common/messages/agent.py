"""Wire types of agent contexts (thesis 7.4.2) and the runner: queues, leases, uploads, output.

Clients ask an agent context (``ctx/<ctx>/request``, AuthEnvelopes) to queue a
controller for one agent (:class:`ControlRequest`), cancel it
(:class:`CancelControl`), read the queues (:class:`QueueStateRequest`), and,
with the manage right, change the settings (:class:`ContextSettings`) or stop
the running controller (:class:`StopControl`). The context publishes
:class:`AgentEvent` on ``ctx/<ctx>/events`` (beside the chat's RoomEvent),
sealed with its service session.

The context asks a runner (``runner/<runner>/run``) to run an uploaded
controller (:class:`RunRequest`), and to stop it (:class:`RunStop`). The
runner's reply carries a claim sealed with its own session
(:class:`RunAccepted`), whose session id the lease names. Whoever drives an
agent (the runner, or the student's ``wart control``) reports the
controller's output and end on ``ctx/<ctx>/output`` (:class:`ControllerOutput`).

The page's editor keeps each user's controller files in the agent context
(:class:`SaveFile`, :class:`FileListRequest`, :class:`ReadFile`, on the same
``ctx/<ctx>/request``). None of them names a user: the context files them
under the user of the envelope's session, so nobody can name another's.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText

MAX_UPLOAD_BYTES = 64 * 1024
"""An uploaded controller's largest size (the sandbox's pre-check uses the same figure)."""

MAX_OUTPUT_LINE = 1000
OUTPUT_KEPT_LINES = 200
"""A run's last output lines an agent context keeps for whoever comes to it late."""
RunMode = Literal["remote", "deploy"]
"""remote: the student's own machine drives (wart control); deploy: the lab's runner does."""

Upload = Annotated[bytes, msgspec.Meta(max_length=MAX_UPLOAD_BYTES)]
OutputLine = Annotated[str, msgspec.Meta(max_length=MAX_OUTPUT_LINE)]
SlotSeconds = Annotated[float, msgspec.Meta(ge=1.0, le=3600.0)]

DryRunSeconds = Annotated[float, msgspec.Meta(gt=0.0, le=30.0)]

RequestStatusKind = Literal["queued", "running", "finished", "cancelled", "refused"]
ENDED: frozenset[str] = frozenset({"finished", "cancelled", "refused"})
"""The statuses a request ends with (its last)."""


# --- client to agent context -----------------------------------------------------------


class ControlRequest(Message, frozen=True):
    """Queue a controller on an agent (the thesis's AgentControlRequest).

    ``remote``: the requester's own session will drive (the lease names it).
    ``deploy``: ``source`` is uploaded and run by the lab's runner.
    """

    agent: Ident
    mode: RunMode
    source: Upload = b""
    filename: ShortText = "controller.py"


class ControlQueued(Message, frozen=True):
    """The reply to a ControlRequest: where it waits and when it should start."""

    request_id: Ident
    agent: Ident
    position: NonNegInt  # 0: running now; 1: next; ...
    start_eta: float | None  # wall-clock seconds; None while the agent is disabled
    slot_seconds: float


class CancelControl(Message, frozen=True):
    """Withdraw a request (one's own; anyone's with the manage right)."""

    request_id: Ident


class StopControl(Message, frozen=True):
    """Stop the controller running on an agent (manage right: owner or ``kick``)."""

    agent: Ident
    reason: ShortText = ""


class ContextSettings(Message, frozen=True):
    """Change the slot length, or enable/disable remote control (manage right).

    ``enabled`` applies to ``agent`` if given, else to the whole context.
    Fields left None are unchanged.
    """

    slot_seconds: SlotSeconds | None = None
    enabled: bool | None = None
    agent: Ident | None = None


class EmergencyStop(Message, frozen=True):
    """Stop every robot of the arena now and hold it stopped (manage right), or release it.

    ``engaged``: every running controller ends ("emergency stop by <who>"), the
    world stops every robot and refuses commands, and no slot starts until a
    request with ``engaged=False`` releases it. Waiting requests stay queued.
    """

    engaged: bool = True
    reason: ShortText = ""


class TakeOver(Message, frozen=True):
    """Take over the robot ``agent`` while a student's controller runs on it (manage right).

    The student's controller is paused, not ended: the context leases the robot to
    the sender's session (its commands, from the page's keys or the sender's own
    controller, are obeyed; the student's are refused by the world) until a
    :class:`HandBack`, or the student's slot ends. Answered with :class:`TakenOver`.
    """

    agent: Ident
    reason: ShortText = ""


class TakenOver(Message, frozen=True):
    """The reply to a TakeOver: whose run is paused, and until when the sender may drive."""

    agent: Ident
    world: Ident
    request_id: Ident  # the paused request
    user: Ident  # its student
    since: float  # wall-clock s: the take-over's start
    end: float  # the student's slot end: the take-over ends then at the latest


class HandBack(Message, frozen=True):
    """Give a taken-over robot back: the student's controller drives it again for the rest
    of its slot (manage right; any manager may hand back, not only the one who took it)."""

    agent: Ident


class DryRunRequest(Message, frozen=True):
    """Run a controller for a few simulated seconds in a private copy of the arena.

    Needs ``deploy`` on the agent (the same right as queueing it). Answered
    with a :class:`DryRunReport`; nothing is queued and no robot moves.
    """

    agent: Ident
    source: Upload
    filename: ShortText = "controller.py"
    seconds: DryRunSeconds = 5.0


class DryRunCollision(msgspec.Struct, frozen=True, kw_only=True):
    at: float  # simulated seconds since the start of the dry run
    what: Literal["wall", "obstacle", "robot", "object"]
    ident: ShortText = ""  # the obstacle's, robot's or object's id ("" for the arena's walls)


class DryRunReport(Message, frozen=True):
    """What a dry run saw; ``verdict`` is the one line a student reads first.

    ``will_run`` is False when the controller raised, did not load, did not
    answer within the wall-clock limit, or hit something (see CONTROLLERS.md:
    a collision means it would bump the real robot into the arena).
    """

    will_run: bool
    verdict: ShortText  # "will run" / "will NOT run: line 12: ZeroDivisionError ..."
    sim_seconds: float  # simulated time covered
    wall_seconds: float  # how long it took
    steps: NonNegInt = 0  # ticks the controller answered (one robot state each)
    collisions: Annotated[list[DryRunCollision], msgspec.Meta(max_length=100)] = msgspec.field(
        default_factory=list
    )
    saturated: NonNegInt = 0  # wheel commands at (or clamped to) the robot's top speed
    commands: NonNegInt = 0  # wheel commands in all
    error_line: int | None = None  # the controller file's line an exception came from
    error: ShortText = ""
    output: Annotated[list[OutputLine], msgspec.Meta(max_length=50)] = msgspec.field(
        default_factory=list
    )
    # Which robot model the run simulated: "simulated with k1's twin fitted 2026-12-05 by
    # carol" (a real robot's twin, common/twin/) or "the datasheet Khepera".
    model: ShortText = ""


class QueueStateRequest(Message, frozen=True):
    """Ask an agent context for its queues, settings and who drives what."""


# --- a user's files in the agent context (the page's editor) ----------------------------

FILE_NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,60}\.py$"
FileName = Annotated[str, msgspec.Meta(pattern=FILE_NAME_PATTERN, max_length=64)]
"""A plain .py name: no directory, no leading dot, so never a path out of the user's folder."""


class SaveFile(Message, frozen=True):
    """Keep ``source`` as the sender's file ``name`` (replacing one of that name)."""

    name: FileName
    source: Upload


class FileListRequest(Message, frozen=True):
    """The sender's own files, newest first (reply: :class:`FileList`)."""


class FileInfo(msgspec.Struct, frozen=True, kw_only=True):
    name: FileName
    size: NonNegInt
    saved_at: float  # wall-clock seconds


class FileList(Message, frozen=True):
    files: Annotated[list[FileInfo], msgspec.Meta(max_length=64)]
    max_files: NonNegInt  # how many the context keeps per user (the oldest go first)
    max_bytes: NonNegInt  # the largest file it keeps


class ReadFile(Message, frozen=True):
    """One of the sender's own files (reply: :class:`FileContent`; not_found otherwise)."""

    name: FileName


class FileContent(Message, frozen=True):
    name: FileName
    source: Upload
    saved_at: float


# --- agent context state and events ----------------------------------------------------


class QueueEntry(msgspec.Struct, frozen=True, kw_only=True):
    request_id: Ident
    user: Ident
    mode: RunMode
    position: NonNegInt  # 0 running
    start_eta: float | None  # running: when it started
    end: float | None = None  # running: when its slot ends
    # Running and taken over: who drives instead of the student's paused controller, since when.
    taken_by: Ident | None = None
    taken_at: float | None = None


class AgentQueue(msgspec.Struct, frozen=True, kw_only=True):
    agent: Ident
    type: Ident
    enabled: bool
    entries: list[QueueEntry]  # running first (position 0), then the waiting ones in order


class OutputSoFarRequest(Message, frozen=True):
    """Ask an agent context for a run's output so far: a page that comes to the run late
    (a second tab, a reload, a viewer restarted) shows what it missed."""

    request_id: Ident


class OutputSoFar(Message, frozen=True):
    """A run's last output lines (at most OUTPUT_KEPT_LINES); ``first`` counts the lines it
    printed before ``lines[0]``, in the numbering of the OutputLines events' ``first``."""

    request_id: Ident
    agent: Ident
    user: Ident
    first: NonNegInt = 0
    lines: Annotated[list[OutputLine], msgspec.Meta(max_length=OUTPUT_KEPT_LINES)] = msgspec.field(
        default_factory=list
    )


class AgentContextState(Message, frozen=True):
    """Every agent of the context and its queue (reply of QueueStateRequest, and in events)."""

    ctx: Ident
    world: Ident
    slot_seconds: float
    enabled: bool
    agents: list[AgentQueue]
    at: float  # the context's wall clock when it was made
    # Set while the host's emergency stop holds the arena: "emergency stop by <who>: why".
    # No slot starts until it is released (waiting requests stay, held in order).
    estop: ShortText = ""


class RequestStatus(msgspec.Struct, frozen=True, kw_only=True):
    request_id: Ident
    agent: Ident
    user: Ident
    status: RequestStatusKind
    reason: ShortText = ""
    start: float | None = None  # running: the lease's start and end
    end: float | None = None
    # A take-over's steps, sent as a ``running`` status with the reason in words:
    # "taken" (``taken_by`` drives since ``taken_at``; the controller is paused) and
    # "handed_back" (the controller drives again).
    takeover: Literal["taken", "handed_back"] | None = None
    taken_by: Ident | None = None
    taken_at: float | None = None


class RequestStatusQuery(Message, frozen=True):
    """Where one request stands now (reply: :class:`RequestStatusReply`).

    The context publishes each of a request's statuses once, as an AgentEvent; a
    client that missed the last one (it subscribed late, its link blipped) asks
    here instead of guessing from the queues. Its owner or the context's managers.
    """

    request_id: Ident


class RequestStatusReply(Message, frozen=True):
    """A request as the context knows it now.

    ``status`` None: the context never saw the request or has forgotten it
    (it keeps the newest ended requests, a bounded number per user). Otherwise
    its status is ``queued`` (``position``, 1 = next, and ``start_eta``),
    ``running`` (``status.end`` - ``at`` seconds left), or how it ended
    (finished / cancelled / refused with the reason, at ``ended_at``; for a run,
    ``status.start`` and ``status.end`` are its slot's start and end).
    """

    request_id: Ident
    at: float  # the context's wall clock when it answered
    status: RequestStatus | None = None
    position: NonNegInt | None = None
    start_eta: float | None = None
    ended_at: float | None = None

    @property
    def known(self) -> bool:
        return self.status is not None

    @property
    def ended(self) -> bool:
        return self.status is not None and self.status.status in ENDED


class OutputLines(msgspec.Struct, frozen=True, kw_only=True):
    request_id: Ident
    agent: Ident
    user: Ident
    lines: list[OutputLine]
    first: NonNegInt = 0  # how many lines the run printed before these (the context counts)


class AgentEvent(Message, frozen=True):
    """An agent context's news, published on ``ctx/<ctx>/events`` beside RoomEvents."""

    ctx: Ident
    state: AgentContextState | None = None
    request: RequestStatus | None = None
    output: OutputLines | None = None


# --- whoever drives, to the agent context ----------------------------------------------


class ControllerOutput(Message, frozen=True):
    """Lines a running controller printed, and its end (sealed, ``ctx/<ctx>/output``).

    Accepted from the session its lease names (the runner, or the student's
    ``wart control``). ``done`` with ``reason`` says the controller has ended.
    """

    request_id: Ident
    lines: Annotated[list[OutputLine], msgspec.Meta(max_length=100)] = msgspec.field(
        default_factory=list
    )
    done: bool = False
    reason: ShortText = ""


# --- agent context to runner -----------------------------------------------------------


class RunRequest(Message, frozen=True):
    """Run an uploaded controller on an agent until ``end`` (sealed, ``lease`` permission)."""

    request_id: Ident
    ctx: Ident
    world: Ident
    agent: Ident
    user: Ident  # whose controller it is (for the logs)
    source: Upload
    end: float  # wall-clock seconds: the sandbox is killed then at the latest
    filename: ShortText = "controller.py"


class RunClaim(Message, frozen=True):
    """Sealed by the runner's session: this session will drive ``request_id``."""

    request_id: Ident
    agent: Ident


class RunAccepted(Message, frozen=True):
    """The runner's reply to a RunRequest: ``claim`` is an AuthEnvelope of a RunClaim."""

    claim: bytes


class DryRun(Message, frozen=True):
    """Dry-run a controller in the runner, against a private copy of ``world`` (sealed, ``lease``).

    The runner builds the copy from the world's public snapshot; the reply is a
    :class:`DryRunReport`. The runner serves these on their own key and
    threads, so a dry run never delays a slot's start or stop.
    """

    ctx: Ident
    world: Ident
    agent: Ident
    user: Ident
    source: Upload
    filename: ShortText = "controller.py"
    seconds: DryRunSeconds = 5.0


class RunStop(Message, frozen=True):
    """Stop a run early (sealed, ``lease`` permission)."""

    request_id: Ident
    reason: ShortText = "stopped"


MAX_CHECKED_RUNS = 256  # more than a context ever runs at once on one runner


class RunCheck(Message, frozen=True):
    """Which of ``request_ids`` does the runner still run? (sealed, ``lease`` permission)

    An agent context asks when the runner's liveliness token went: a runner cut
    off by a router blip still runs them, one that crashed and came back runs
    none of them (docs/OPERATIONS.md, on a runner that dies).
    """

    request_ids: Annotated[list[Ident], msgspec.Meta(max_length=MAX_CHECKED_RUNS)]


class RunCheckReply(Message, frozen=True):
    """The runner's answer to a RunCheck: those of the asked requests it runs now."""

    running: Annotated[list[Ident], msgspec.Meta(max_length=MAX_CHECKED_RUNS)]


__all__ = [
    "ENDED",
    "MAX_OUTPUT_LINE",
    "MAX_UPLOAD_BYTES",
    "OUTPUT_KEPT_LINES",
    "AgentContextState",
    "AgentEvent",
    "AgentQueue",
    "CancelControl",
    "ContextSettings",
    "ControlQueued",
    "ControlRequest",
    "ControllerOutput",
    "DryRun",
    "DryRunCollision",
    "DryRunReport",
    "DryRunRequest",
    "DryRunSeconds",
    "EmergencyStop",
    "FileContent",
    "FileInfo",
    "FileList",
    "FileListRequest",
    "HandBack",
    "OutputLines",
    "OutputSoFar",
    "OutputSoFarRequest",
    "QueueEntry",
    "QueueStateRequest",
    "ReadFile",
    "RequestStatus",
    "RequestStatusQuery",
    "RequestStatusReply",
    "RunAccepted",
    "RunCheck",
    "RunCheckReply",
    "RunClaim",
    "RunMode",
    "RunRequest",
    "RunStop",
    "SaveFile",
    "StopControl",
    "TakeOver",
    "TakenOver",
]
