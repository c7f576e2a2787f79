"""Wire types of the grader: submissions, episodes on a runner, leaderboards.

A student sends a sealed :class:`Submit` to the grader (``grader/<g>/request``);
the grader runs the assignment's seeded episodes, each an :class:`Episode` on a
runner (``runner/<r>/episode``, sealed with the grader's service session,
``lease``), answered with an :class:`EpisodeReport`: what happened in the
episode (zones reached and when, objects delivered, collisions, time) and how
it ended (``cause``). The grader scores it and keeps it; students ask for
their submissions (:class:`SubmissionsQuery`) and the leaderboard
(:class:`LeaderboardQuery`) on the same key.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.agent import Upload
from common.messages.base import Ident, Message, NonNegInt, ShortText
from common.messages.world import WorldSnapshot

MAX_MAP_BYTES = 256 * 1024
MAX_EPISODE_S = 300.0

EpisodeCause = Literal[
    "ok",  # ran its whole time
    "finished",  # the controller returned before the time limit (scored as it stood)
    "exception",  # student: raised (error_line says where)
    "timeout",  # student: did not answer in wall-clock time (a loop)
    "memory",  # student: out of memory
    "output",  # student: printed a flood
    "cpu",  # student: used its CPU time
    "ended",  # student: the controller process ended otherwise
    "lab",  # the lab: runner died, sandbox could not start, no runner answered
    "grader",  # the teacher: the assignment's grader function failed (the run is not charged)
    "hidden",  # not shown to its student yet (the assignment's visibility; ``detail`` says when)
]
STUDENT_CAUSES: frozenset[str] = frozenset(
    {"exception", "timeout", "memory", "output", "cpu", "ended"}
)

MapText = Annotated[str, msgspec.Meta(max_length=MAX_MAP_BYTES)]
EpisodeSeconds = Annotated[float, msgspec.Meta(gt=0.0, le=MAX_EPISODE_S)]


class Episode(Message, frozen=True):
    """One seeded episode of a submission, run by a runner in a private world."""

    submission: Ident
    episode: NonNegInt
    user: Ident
    map: MapText  # the map (maps.py format) as JSON, the assignment's zones added
    agent: Ident  # the robot of the map the controller drives
    seed: int
    x: float
    y: float
    heading: float  # radians
    seconds: EpisodeSeconds
    source: Upload
    filename: ShortText = "controller.py"
    trace: bool = False  # report the robot's path (a competition's heat records it)
    # The assignment's grader function (docs/COURSES.md), run on the episode's data after it.
    grader: Upload | None = None
    grader_filename: ShortText = "grader.py"
    grader_seconds: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 10.0


TRACE_EVERY_S = 0.1  # a traced episode's path: one pose per this many simulated s
MAX_TRACE = int(MAX_EPISODE_S / TRACE_EVERY_S) + 2
TracePoint = tuple[float, float, float, float]  # simulated s, x mm, y mm, heading rad
MAX_TRACE_ROWS = 200  # a traced episode's frames carry at most this many rows (robots, objects)
# simulated s, then x, y, heading of each of the snapshot's rows in order
TraceFrame = tuple[float, Annotated[list[float], msgspec.Meta(max_length=3 * MAX_TRACE_ROWS)]]


class EpisodeReport(Message, frozen=True):
    """What an episode saw and how it ended."""

    cause: EpisodeCause
    detail: ShortText = ""  # the one line a student reads ("line 7: ZeroDivisionError: ...")
    error_line: int | None = None
    sim_seconds: float = 0.0
    wall_seconds: float = 0.0
    steps: NonNegInt = 0
    # new contacts of the robot, by what it hit: wall, obstacle, robot, object
    collisions: dict[str, NonNegInt] = msgspec.field(default_factory=dict)
    reached: dict[str, float] = msgspec.field(default_factory=dict)  # zone -> first sim s
    delivered: dict[str, float] = msgspec.field(default_factory=dict)  # object -> sim s in a nest
    distance_mm: float = 0.0
    output: Annotated[list[ShortText], msgspec.Meta(max_length=20)] = msgspec.field(
        default_factory=list
    )
    trace: Annotated[list[TracePoint], msgspec.Meta(max_length=MAX_TRACE)] = msgspec.field(
        default_factory=list
    )
    # A traced episode's world (for a replay) and every row's pose each TRACE_EVERY_S.
    snapshot: WorldSnapshot | None = None
    frames: Annotated[list[TraceFrame], msgspec.Meta(max_length=MAX_TRACE)] = msgspec.field(
        default_factory=list
    )
    # What the assignment's grader function returned, or why it gave nothing (the teacher's).
    grader_metrics: Annotated[dict[str, float], msgspec.Meta(max_length=32)] = msgspec.field(
        default_factory=dict
    )
    grader_error: ShortText = ""
    grader_line: int | None = None


MAX_PER_HEAT = 16


class HeatEntry(msgspec.Struct, frozen=True, kw_only=True):
    """One team's entry in a heat: its controller on one robot of the map."""

    submission: Ident
    user: Ident
    agent: Ident
    x: float
    y: float
    heading: float  # radians
    source: Upload
    filename: ShortText = "controller.py"


class Heat(Message, frozen=True):
    """Several entries' controllers in one world at once (a competition's heat): each drives
    its own robot, stepped in lockstep together; answered with :class:`HeatReport`."""

    competition: Ident
    heat: NonNegInt
    map: MapText
    seed: int
    seconds: EpisodeSeconds
    entries: Annotated[list[HeatEntry], msgspec.Meta(min_length=1, max_length=MAX_PER_HEAT)]


class HeatReport(Message, frozen=True):
    """Each entry's report (as an episode's, in the heat's order), the world and its frames."""

    entries: Annotated[list[EpisodeReport], msgspec.Meta(max_length=MAX_PER_HEAT)]
    snapshot: WorldSnapshot | None = None
    frames: Annotated[list[TraceFrame], msgspec.Meta(max_length=MAX_TRACE)] = msgspec.field(
        default_factory=list
    )


class GradeData(Message, frozen=True):
    """Run an assignment's grader function on an episode's data (a real attempt's: the
    grader built it from the recording; the structure of docs/COURSES.md, as JSON)."""

    grader: Upload
    episode: Annotated[bytes, msgspec.Meta(max_length=4 * 1024 * 1024)]
    grader_filename: ShortText = "grader.py"
    grader_seconds: Annotated[float, msgspec.Meta(gt=0.0, le=60.0)] = 10.0


class GradeResult(Message, frozen=True):
    """What grade() returned, or why it gave nothing (the teacher's fault)."""

    metrics: Annotated[dict[str, float], msgspec.Meta(max_length=32)] = msgspec.field(
        default_factory=dict
    )
    error: ShortText = ""
    line: int | None = None


# --- student / teacher to the grader ----------------------------------------------------

SubmissionStatus = Literal["queued", "running", "graded", "failed"]


class Submit(Message, frozen=True):
    """Grade this controller on an assignment (the envelope's user is the student)."""

    assignment: Ident
    source: Upload
    filename: ShortText = "controller.py"


class SubmitAccepted(Message, frozen=True):
    submission: Ident
    position: NonNegInt  # in the grader's queue (1 = next)
    used: NonNegInt  # graded runs counted in the rolling 24 h, this one included
    quota: NonNegInt
    late_days: NonNegInt = 0
    note: ShortText = ""


class SubmissionsQuery(Message, frozen=True):
    """The sender's submissions to an assignment (a teacher: ``user`` names another)."""

    assignment: Ident
    user: Ident | None = None
    submission: Ident | None = None


class EpisodeReplayGet(Message, frozen=True):
    """A chunk of one graded episode's recording (its student, or the course's teachers).

    Answered with a :class:`RecordingChunk`; ask again from ``offset`` until ``total``.
    """

    assignment: Ident
    submission: Ident
    episode: NonNegInt
    offset: NonNegInt = 0


MAX_TERMS = 16
# A term of the rule as written ("- 5 * collisions()"), and its value in the episode.
ScoreTerm = tuple[ShortText, float]


class EpisodeResult(msgspec.Struct, frozen=True, kw_only=True):
    episode: NonNegInt
    seed: int
    cause: EpisodeCause
    detail: ShortText = ""
    error_line: int | None = None
    score: float | None = None  # None: not scored (a lab fault left it)
    metrics: dict[str, float] = msgspec.field(default_factory=dict)
    lab_reruns: NonNegInt = 0  # how often a lab fault made it run again, free
    real: bool = False  # the real-robot attempt's row (an arena's agent context ran it)
    # The score term by term, as the rule adds them up (the student sees where points went).
    terms: Annotated[list[ScoreTerm], msgspec.Meta(max_length=MAX_TERMS)] = msgspec.field(
        default_factory=list
    )
    # The controller's last printed lines (a failed episode's traceback among them).
    output: Annotated[list[ShortText], msgspec.Meta(max_length=20)] = msgspec.field(
        default_factory=list
    )
    replay: bool = False  # its recording is kept: EpisodeReplayGet fetches it


class SubmissionInfo(msgspec.Struct, frozen=True, kw_only=True):
    submission: Ident
    assignment: Ident
    user: Ident
    status: SubmissionStatus
    submitted_at: float
    graded_at: float | None = None
    mean: float | None = None
    min: float | None = None
    late_days: NonNegInt = 0
    penalty: float = 0.0
    counted: bool = True  # against the quota (False: the lab's fault)
    message: ShortText = ""
    episodes: Annotated[list[EpisodeResult], msgspec.Meta(max_length=100)] = msgspec.field(
        default_factory=list
    )


class SubmissionList(Message, frozen=True):
    submissions: Annotated[list[SubmissionInfo], msgspec.Meta(max_length=500)]


class MyAssignments(Message, frozen=True):
    """The assignments of the sender's courses (the page's Course folder)."""


class AssignmentInfo(msgspec.Struct, frozen=True, kw_only=True):
    name: Ident
    course: Ident
    title: ShortText
    opens: float
    deadline: float
    episodes: NonNegInt
    time_limit: float
    score_name: ShortText
    unit: ShortText
    order: Literal["higher", "lower"]
    quota: NonNegInt
    rule: ShortText = ""


class AssignmentList(Message, frozen=True):
    assignments: Annotated[list[AssignmentInfo], msgspec.Meta(max_length=500)]


PSEUDONYM_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9 _.\-]{0,31}$"


class SetPseudonym(Message, frozen=True):
    """The name the sender's scores show under on the leaderboards of the assignment's course
    ("" for their roster name again); unique within the course. Answered with OkReply."""

    assignment: Ident
    pseudonym: Annotated[str, msgspec.Meta(max_length=32)] = ""


class LeaderboardQuery(Message, frozen=True):
    assignment: Ident


class LeaderEntry(msgspec.Struct, frozen=True, kw_only=True):
    rank: int
    name: ShortText  # the display name (or the account) of the student
    score: float
    submission: Ident
    at: float
    real: float | None = None  # that submission's real-robot attempt's score, once run


class Leaderboard(Message, frozen=True):
    assignment: Ident
    score_name: ShortText
    unit: ShortText
    order: Literal["higher", "lower"]
    hidden: bool  # hidden from students until the deadline (a teacher still sees)
    deadline: float
    hidden_until: ShortText = ""  # when a hidden board is shown ("" with hidden: the deadline)
    entries: Annotated[list[LeaderEntry], msgspec.Meta(max_length=5000)] = msgspec.field(
        default_factory=list
    )


# --- competitions: every team's entry in heats, standings published live -----------------

EntryCause = Literal[
    "waiting",
    "ok",
    "finished",
    "exception",
    "timeout",
    "memory",
    "output",
    "cpu",
    "ended",
    "lab",
    "grader",
]


class CompetitionRun(Message, frozen=True):
    """Run a competition on an assignment (the course's teachers): each team's latest (or
    best) graded submission is its entry, one entry per heat. Answered with the first
    :class:`Standings` (every entry waiting); the rest is published as heats end."""

    assignment: Ident
    name: Ident | None = None  # default: the assignment's name and the time
    pick: Literal["latest", "best"] = "latest"
    per_heat: Annotated[int, msgspec.Meta(ge=1, le=MAX_PER_HEAT)] = 1


class CompetitionQuery(Message, frozen=True):
    """A competition's standings (anyone in its course)."""

    name: Ident


class StandingEntry(msgspec.Struct, frozen=True, kw_only=True):
    rank: NonNegInt  # 0 while not run yet
    team: ShortText
    user: Ident  # whose submission is the team's entry
    submission: Ident
    heat: NonNegInt  # 1-based
    score: float | None = None
    cause: EntryCause = "waiting"
    detail: ShortText = ""
    recording: ShortText = ""  # the heat's MCAP file (on the grader's host)


class Standings(Message, frozen=True):
    competition: Ident
    assignment: Ident
    course: Ident
    score_name: ShortText
    unit: ShortText
    order: Literal["higher", "lower"]
    status: Literal["running", "finished", "stopped"]  # stopped: the grader stopped mid-way
    heats: NonNegInt
    heat: NonNegInt = 0  # the heat in progress (0: none)
    entries: Annotated[list[StandingEntry], msgspec.Meta(max_length=500)] = msgspec.field(
        default_factory=list
    )
    at: float = 0.0


# --- live changes, and the teacher's view of a class ----------------------------------------


class CompetitionChanged(Message, frozen=True):
    """A competition's standings changed (a heat began or ended, it finished): no entry,
    no score; each page asks the grader (CompetitionQuery) for what its user may see."""

    competition: Ident
    assignment: Ident
    course: Ident
    status: Literal["running", "finished", "stopped"]
    heat: NonNegInt = 0
    at: float = 0.0


class GradingChanged(Message, frozen=True):
    """A submission of the course changed state: pages showing that assignment ask again.

    Deliberately no score and no student: each page asks the grader for what its
    user may see (a hidden-until-deadline leaderboard stays in the grader for students)."""

    course: Ident
    assignment: Ident
    submission: Ident
    status: SubmissionStatus
    at: float


class GraderQueue(Message, frozen=True):
    """How much grading waits (``grader/<name>/queue``, put every few seconds): the
    submissions queued and those being graded. What a cluster scales its runners on."""

    grader: Ident
    queued: NonNegInt
    running: NonNegInt
    at: float  # wall clock of the grader


class ClassQuery(Message, frozen=True):
    """The teacher's view: every student of a course with their latest submission (the
    course's teachers; admins). ``course`` None: every course the asker teaches (none for a
    student, who is refused a named course)."""

    course: Ident | None = None


class ClassRow(msgspec.Struct, frozen=True, kw_only=True):
    user: Ident
    name: ShortText  # the roster's display name ("" if none)
    team: ShortText = ""
    assignment: Ident | None = None  # of the latest submission (None: none yet)
    submission: Ident | None = None
    status: SubmissionStatus | None = None
    submitted_at: float | None = None
    queue_place: NonNegInt | None = None  # queued: 1 = graded next
    score: float | None = None  # the latest graded submission's, after penalty
    failure: ShortText = ""  # how the last run that failed ended ("exception: line 7: ...")
    submissions: NonNegInt = 0


class ClassTable(Message, frozen=True):
    course: Ident
    title: ShortText
    rows: Annotated[list[ClassRow], msgspec.Meta(max_length=5000)] = msgspec.field(
        default_factory=list
    )
    at: float = 0.0


class ClassTables(Message, frozen=True):
    tables: Annotated[list[ClassTable], msgspec.Meta(max_length=100)] = msgspec.field(
        default_factory=list
    )


__all__ = [
    "MAX_EPISODE_S",
    "MAX_MAP_BYTES",
    "MAX_PER_HEAT",
    "MAX_TRACE",
    "MAX_TRACE_ROWS",
    "PSEUDONYM_PATTERN",
    "STUDENT_CAUSES",
    "TRACE_EVERY_S",
    "AssignmentInfo",
    "AssignmentList",
    "ClassQuery",
    "ClassRow",
    "ClassTable",
    "ClassTables",
    "CompetitionChanged",
    "CompetitionQuery",
    "CompetitionRun",
    "EntryCause",
    "Episode",
    "EpisodeCause",
    "EpisodeReplayGet",
    "EpisodeReport",
    "EpisodeResult",
    "GradeData",
    "GradeResult",
    "GraderQueue",
    "GradingChanged",
    "Heat",
    "HeatEntry",
    "HeatReport",
    "LeaderEntry",
    "Leaderboard",
    "LeaderboardQuery",
    "MyAssignments",
    "SetPseudonym",
    "StandingEntry",
    "Standings",
    "SubmissionInfo",
    "SubmissionList",
    "SubmissionStatus",
    "SubmissionsQuery",
    "Submit",
    "SubmitAccepted",
    "TraceFrame",
    "TracePoint",
]
