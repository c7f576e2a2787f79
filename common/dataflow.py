"""The lab's dataflow in one table: each key, what travels on it, who produces it, who consumes it.

One :class:`Flow` a key and pattern. Derived from this table, and from nowhere
else: the routers' access-control grants of each role
(services/lab/zsecurity.py), the priority and congestion control of each put
(:func:`common.qos.of`), and the key table of docs/ARCHITECTURE.md (a test
checks it; ``python -m common.dataflow_doc`` prints it).

Roles are the names the routers' access control knows (certificate common
names): one per kind of service, plus ``student`` and ``admin`` for people's
own tools and ``viewer`` for the web page, which acts for its users.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from common import keys
from common import messages as m
from common.keys import AliveKind
from common.messages import Message

KeyBuilder = Callable[..., str]


class Pattern(StrEnum):
    """How a key is used: Zenoh's three patterns."""

    PUT = "put"  # producers put (publish), consumers subscribe
    QUERY = "query"  # producers serve a queryable, consumers ask
    TOKEN = "token"  # producers hold liveliness tokens, consumers watch them


class Urgency(StrEnum):
    """How a put travels when a link is busy (common/qos.py maps each to Zenoh's options)."""

    FRAMES = "frames"  # Zenoh's default: a stale one is worth nothing once the next exists
    WORDS = "words"  # a person reads it, or a run or a check waits on it: above the frames
    STOP = "stop"  # an emergency stop: before anything else


@dataclass(frozen=True)
class Exchange:
    """What travels once: a message put, or a request and the replies it may get."""

    message: type[Message] | None  # None: a query with no payload
    replies: tuple[type[Message], ...] = ()


@dataclass(frozen=True)
class Flow:
    """One key's use: who produces, who consumes, what travels, how urgently."""

    key: KeyBuilder
    pattern: Pattern
    producers: tuple[str, ...]
    consumers: tuple[str, ...]
    exchanges: tuple[Exchange, ...] = ()
    # AuthEnvelope around each message: sealed by its sender's session, or MACed
    sealed: bool = False
    urgency: Urgency = Urgency.FRAMES
    # Ids the key's pattern fixes (an alive token's kind), the rest are '*'
    fixed: tuple[tuple[str, Any], ...] = ()
    note: str = ""

    def pattern_key(self) -> str:
        """The key relative to ``wart/<realm>/``, every free id a ``*``."""
        return keys.wildcard(self.key, **dict(self.fixed))


def _ask(message: type[Message] | None, *replies: type[Message]) -> Exchange:
    return Exchange(message, replies)


def _put(
    key: KeyBuilder,
    producers: tuple[str, ...],
    consumers: tuple[str, ...],
    *messages: type[Message],
    **options: Any,
) -> Flow:
    return Flow(key, Pattern.PUT, producers, consumers, tuple(map(Exchange, messages)), **options)


def _query(
    key: KeyBuilder,
    producers: tuple[str, ...],
    consumers: tuple[str, ...],
    *exchanges: Exchange,
    **options: Any,
) -> Flow:
    return Flow(key, Pattern.QUERY, producers, consumers, exchanges, **options)


def _ok(*messages: type[Message]) -> tuple[Exchange, ...]:
    """Requests answered by a bare ``OkReply``."""
    return tuple(Exchange(message, (m.OkReply,)) for message in messages)


SEALED: dict[str, Any] = {"sealed": True}
WORDS: dict[str, Any] = {"sealed": True, "urgency": Urgency.WORDS}


# Who is who (the routers' role names).
PEOPLE = ("student", "admin", "viewer")  # people's tools, and the page acting for them
# Services that log in (or check tokens) with the registry and follow presence.
SERVICES = ("chat", "agent", "engine", "bridge", "runner", "grader", "lti", "host")
CONTEXTS = ("chat", "agent")
WORLDS = ("engine", "bridge")
# Every role, in the order certificates are listed (services/lab/pki.py).
ROLES = (
    "router",
    "host",
    "registry",
    "chat",
    "engine",
    "bridge",
    "agent",
    "runner",
    "grader",
    "lti",
    "viewer",
    "camera",
    "student",
    "admin",
)

_REGISTRY_CLIENTS = (*SERVICES, *PEOPLE)
_ALIVE: tuple[tuple[AliveKind, tuple[str, ...]], ...] = (
    (AliveKind.REGISTRY, ("registry",)),
    (AliveKind.USER, PEOPLE),
    (AliveKind.CONTEXT, CONTEXTS),
    (AliveKind.WORLD, WORLDS),
    (AliveKind.RUNNER, ("runner",)),
    (AliveKind.GRADER, ("grader",)),
    (AliveKind.LTI, ("lti",)),
    (AliveKind.HOST, ("host",)),
    (AliveKind.VIEWER, ("viewer",)),
    (AliveKind.CAMERA, ("camera",)),
)
_ADMIN_CHANGES: tuple[type[Message], ...] = (
    *(m.AddUser, m.SetPassword, m.RemoveUser, m.Grant, m.Ungrant, m.KickFromServer),
    *(m.RenameServer, m.UnlockLogins, m.BanUser, m.LiftBan, m.ClearThrottle),
)
_QUEUE_CHANGES = (m.CancelControl, m.StopControl, m.ContextSettings, m.EmergencyStop, m.HandBack)

FLOWS: tuple[Flow, ...] = (
    # -- presence
    *(Flow(keys.alive, Pattern.TOKEN, who, (), fixed=(("kind", kind),)) for kind, who in _ALIVE),
    Flow(
        keys.alive_all,
        Pattern.TOKEN,
        (),
        ("registry", *_REGISTRY_CLIENTS),
        note="the directory, supervisors and contexts follow every token",
    ),
    # -- the registry
    _query(
        keys.registry_login,
        ("registry",),
        _REGISTRY_CLIENTS,
        _ask(m.SealedLogin, m.LoginReply),
        note="a gateway's `LoginVouch` rides with the login of a browser's user",
    ),
    _query(keys.registry_logout, ("registry",), _REGISTRY_CLIENTS, *_ok(m.LogoutRequest), **SEALED),
    _query(
        keys.registry_directory,
        ("registry",),
        _REGISTRY_CLIENTS,
        _ask(m.DirectoryRequest, m.DirectoryReply),
        _ask(m.UserKeysRequest, m.UserKeysReply),
        *_ok(m.MailboxDeposit),
        _ask(m.MailboxClaim, m.MailboxContents),
        *_ok(m.ResumeCheck),
        **SEALED,
    ),
    _query(
        keys.registry_admin,
        ("registry",),
        PEOPLE,
        _ask(m.ListUsers, m.UserList),
        _ask(m.ListThrottles, m.ThrottleList),
        *_ok(*_ADMIN_CHANGES),
        **SEALED,
        note="each change and each refusal appended to the audit trail",
    ),
    _query(
        keys.registry_audit,
        ("registry",),
        PEOPLE,
        _ask(m.AuditQuery, m.AuditList),
        **SEALED,
        note="admins only",
    ),
    _put(
        keys.registry_report,
        CONTEXTS,
        ("registry",),
        m.AuditReport,
        **WORDS,
        note="services' privileged actions, appended to the audit trail",
    ),
    _query(
        keys.registry_lti,
        ("registry",),
        ("lti",),
        _ask(m.LtiAccountRequest, m.LtiAccount),
        **SEALED,
        note="the lti role only",
    ),
    _query(
        keys.registry_twins,
        ("registry",),
        ("runner", *PEOPLE),
        _ask(m.TwinQuery, m.TwinReply),
        _ask(m.TwinListQuery, m.TwinList),
        _ask(m.TwinSave, m.TwinSaved),
        **SEALED,
        note="by arena and robot; who may: docs/CALIBRATION.md",
    ),
    _query(
        keys.registry_revocations,
        ("registry",),
        _REGISTRY_CLIENTS,
        _ask(m.RevocationsRequest, m.SignedRevocations),
    ),
    _put(
        keys.registry_revocations,
        ("registry",),
        _REGISTRY_CLIENTS,
        m.SignedRevocations,
        urgency=Urgency.WORDS,
        note="on each revocation",
    ),
    _put(
        keys.user_inbox,
        ("registry", *PEOPLE),
        _REGISTRY_CLIENTS,
        m.PrivateMessage,
        m.KickNotice,
        **WORDS,
        note="the registry puts kick notices",
    ),
    # -- contexts
    _query(keys.ctx_join, CONTEXTS, PEOPLE, _ask(m.JoinRoom, m.JoinReply), **SEALED),
    _query(keys.ctx_leave, CONTEXTS, PEOPLE, *_ok(m.LeaveRoom), **SEALED),
    _query(
        keys.ctx_state,
        CONTEXTS,
        ("registry", *PEOPLE),
        _ask(m.ContextInfoRequest, m.ContextInfo),
        **SEALED,
        note="the registry's directory asks",
    ),
    _query(
        keys.ctx_request,
        CONTEXTS,
        PEOPLE,
        *_ok(m.ChatSay, m.UserRemovalRequest),
        _ask(m.ControlRequest, m.ControlQueued),
        *_ok(*_QUEUE_CHANGES),
        _ask(m.TakeOver, m.TakenOver),
        _ask(m.QueueStateRequest, m.AgentContextState),
        _ask(m.OutputSoFarRequest, m.OutputSoFar),
        _ask(m.RecordingListRequest, m.RecordingList),
        _ask(m.RecordingGet, m.RecordingChunk),
        *_ok(m.SaveFile),
        _ask(m.FileListRequest, m.FileList),
        _ask(m.ReadFile, m.FileContent),
        **SEALED,
        note="chat rooms answer the chat requests; agent contexts all",
    ),
    _put(keys.ctx_in, PEOPLE, CONTEXTS, m.ChatSay, **WORDS, note="chat lines, fire and forget"),
    _put(keys.ctx_events, CONTEXTS, PEOPLE, m.RoomEvent, m.AgentEvent, **WORDS),
    _put(
        keys.ctx_output,
        ("runner", *PEOPLE),
        ("agent",),
        m.ControllerOutput,
        **WORDS,
        note="from the lease holder (runner, wart control)",
    ),
    _query(
        keys.ctx_dryrun,
        ("agent",),
        PEOPLE,
        _ask(m.DryRunRequest, m.DryRunReport),
        **SEALED,
        note="2 worker threads",
    ),
    _query(
        keys.ctx_status,
        ("agent",),
        PEOPLE,
        _ask(m.RequestStatusQuery, m.RequestStatusReply),
        **SEALED,
        note="the request's owner or the context's managers",
    ),
    # -- runners
    _query(
        keys.runner_run,
        ("runner",),
        ("agent", *PEOPLE),
        _ask(m.RunRequest, m.RunAccepted),
        *_ok(m.RunStop),
        _ask(m.RunCheck, m.RunCheckReply),
        **SEALED,
        note="`lease` services only (the runner checks)",
    ),
    _query(
        keys.runner_dryrun,
        ("runner",),
        ("agent",),
        _ask(m.DryRun, m.DryRunReport),
        **SEALED,
        note="2 worker threads",
    ),
    _query(
        keys.runner_episode,
        ("runner",),
        ("grader",),
        _ask(m.Episode, m.EpisodeReport),
        **SEALED,
        note="2 worker threads",
    ),
    _query(
        keys.runner_heat,
        ("runner",),
        ("grader",),
        _ask(m.Heat, m.HeatReport),
        **SEALED,
        note="a competition's heat",
    ),
    _query(
        keys.runner_grade,
        ("runner",),
        ("grader",),
        _ask(m.GradeData, m.GradeResult),
        **SEALED,
        note="a teacher's grader function on a real attempt",
    ),
    # -- the grader
    _query(
        keys.grader_request,
        ("grader",),
        ("lti", *PEOPLE),
        _ask(m.Submit, m.SubmitAccepted),
        _ask(m.SubmissionsQuery, m.SubmissionList),
        _ask(m.LeaderboardQuery, m.Leaderboard),
        *_ok(m.SetPseudonym),
        _ask(m.MyAssignments, m.AssignmentList),
        _ask(m.CompetitionRun, m.Standings),
        _ask(m.CompetitionQuery, m.Standings),
        _ask(m.ClassQuery, m.ClassTables),
        _ask(m.EpisodeReplayGet, m.RecordingChunk),
        **SEALED,
        note="course members; 2 worker threads",
    ),
    _put(
        keys.grader_standings,
        ("grader",),
        PEOPLE,
        m.CompetitionChanged,
        **WORDS,
        note="as each heat starts and ends; no entry: each reader asks",
    ),
    _put(
        keys.grader_changed,
        ("grader",),
        PEOPLE,
        m.GradingChanged,
        **WORDS,
        note="no score, no student: each reader asks for what it may see",
    ),
    _put(
        keys.grader_graded,
        ("grader",),
        ("lti",),
        m.Graded,
        **WORDS,
        note="no student, no score: the lti service asks, passes grades back",
    ),
    _put(
        keys.grader_queue,
        ("grader",),
        ("host",),
        m.GraderQueue,
        note="every 5 s; runners scaled on it",
    ),
    # -- worlds (engines and bridges)
    _put(keys.world_frame, WORLDS, ("agent", "runner", *PEOPLE), m.WorldFrame, note="each tick"),
    _put(
        keys.world_layout,
        WORLDS,
        ("agent", "camera"),
        m.WorldLayout,
        urgency=Urgency.WORDS,
        note="once per change of the world's rows",
    ),
    _put(keys.world_sensors, WORLDS, PEOPLE, m.SensorBatch, note="each tick while subscribed"),
    _put(
        keys.world_samples,
        WORLDS,
        ("agent", "runner", *PEOPLE),
        m.SampleBundle,
        note="the leased agents' samples, each tick while subscribed",
    ),
    _put(
        keys.world_commands,
        ("runner", *PEOPLE),
        (*WORLDS, "agent"),
        m.CommandBundle,
        m.MacCommandBundle,
        note="each item checked as if put on its agent's cmd key; recorded by its context",
    ),
    _put(
        keys.world_estop,
        ("agent",),
        WORLDS,
        m.WorldStop,
        **SEALED,
        urgency=Urgency.STOP,
        note="republished every 1 s while engaged",
    ),
    _query(
        keys.world_snapshot,
        WORLDS,
        ("agent", "runner", "camera", *PEOPLE),
        _ask(None, m.WorldSnapshot),
    ),
    _query(
        keys.world_edit,
        WORLDS,
        PEOPLE,
        _ask(m.WorldEdit, m.EditResult, m.ErrorReply),
        **SEALED,
        note="`edit_map`; a bridge refuses",
    ),
    _query(
        keys.world_map,
        WORLDS,
        PEOPLE,
        _ask(m.MapRequest, m.EditResult, m.ErrorReply),
        **SEALED,
        note="`edit_map`; a bridge refuses",
    ),
    _query(
        keys.world_robots,
        WORLDS,
        PEOPLE,
        _ask(m.RobotTypeRequest, m.RobotTypeReply, m.ErrorReply),
        **SEALED,
        note="saving needs `edit_map`; a bridge refuses",
    ),
    _put(
        keys.world_tracked,
        ("camera",),
        ("agent", "bridge", *PEOPLE),
        m.TrackedPoses,
        note="each camera frame",
    ),
    _put(keys.camera_frame, ("camera",), (), m.CameraFrame),
    _put(keys.camera_floor, ("camera",), (), m.CameraFrame),
    _put(keys.camera_status, ("camera",), (), m.CameraStatus),
    _put(
        keys.camera_all,
        (),
        ("agent", *PEOPLE),
        note="every camera's image, floor and status over a world",
    ),
    _put(
        keys.agent_sensors,
        WORLDS,
        ("agent", "runner", *PEOPLE),
        m.SensorSample,
        note="each tick while watched or leased",
    ),
    Flow(
        keys.agent_watch,
        Pattern.TOKEN,
        ("agent", "runner", *PEOPLE),
        WORLDS,
        note="whoever reads an agent's sensors: the world's cue to publish them",
    ),
    _put(
        keys.agent_cmd,
        ("runner", *PEOPLE),
        (*WORLDS, "agent"),
        m.AgentCommand,
        m.MacCommand,
        **SEALED,
        note="the lease holder's, sealed or MACed; recorded by the agent's context",
    ),
    _put(
        keys.agent_lease,
        ("agent",),
        (*WORLDS, "runner"),
        m.Lease,
        **WORDS,
        note="republished periodically",
    ),
    # -- hosts
    _put(keys.host_load, ("host",), PEOPLE, m.HostLoad, note="every limits.load_period_s"),
    _query(keys.host_load, ("host",), PEOPLE, _ask(m.LoadRequest, m.HostLoad)),
    _query(
        keys.host_spawn,
        ("host",),
        PEOPLE,
        _ask(m.SpawnArena, m.ArenaReply),
        _ask(m.SpawnRoom, m.RoomReply),
        *_ok(m.StopArena, m.StopRoom),
        **SEALED,
        note="the `host` permission",
    ),
)


def flows_of(builder: KeyBuilder) -> list[Flow]:
    return [f for f in FLOWS if f.key is builder]


def urgency_of(builder: KeyBuilder) -> Urgency:
    """How puts on ``builder``'s keys travel (every put flow of one key agrees)."""
    found = {f.urgency for f in flows_of(builder) if f.pattern is Pattern.PUT}
    if len(found) != 1:
        raise KeyError(f"no one put flow for {builder.__name__} in common/dataflow.py")
    return found.pop()


# What each side of a pattern may do, in the routers' words (services/lab/zsecurity.py).
PRODUCER_VERB = {Pattern.PUT: "pub", Pattern.QUERY: "serve", Pattern.TOKEN: "token"}
CONSUMER_VERB = {Pattern.PUT: "sub", Pattern.QUERY: "ask", Pattern.TOKEN: "watch"}


def role_verbs(role: str) -> list[tuple[str, str]]:
    """(verb, key pattern) of every right ``role`` needs, in the table's order."""
    found: list[tuple[str, str]] = []
    for flow in FLOWS:
        if role in flow.producers:
            found.append((PRODUCER_VERB[flow.pattern], flow.pattern_key()))
        if role in flow.consumers:
            found.append((CONSUMER_VERB[flow.pattern], flow.pattern_key()))
    return found
