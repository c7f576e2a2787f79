"""An assignment file (TOML) a teacher writes, checked whole: every problem with its field.

See docs/COURSES.md for the format. What is kept (in the registry's database,
services/grader/grading_db.py) is the checked :class:`Assignment` and the
map it names, resolved once: a later edit of maps/ never changes a running
assignment's world.
"""

from __future__ import annotations

import ast
import datetime as dt
import json
import math
import time
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from common.handed_in import load_toml
from common.keys import is_ident
from common.messages import MAX_EPISODE_S, MAX_MAP_BYTES
from common.sim2d import maps
from services.grader.score import Rule, RuleError, parse_rule

GRADER_SECONDS = 10.0  # a grader function's default wall-clock time per episode
MAX_GRADER_SECONDS = 60.0

MAX_FILE_BYTES = 64 * 1024
MAX_EPISODES = 20
MAX_QUOTA = 1000
DAY_S = 86400.0
# When a student sees an episode's result: at once, after the deadline, once the teacher
# releases the results (`wart course release`), as Gradescope's tests are.
VISIBILITIES = ("now", "after_deadline", "after_release")


class AssignmentError(ValueError):
    """The file is not a valid assignment: ``problems`` lists each field's."""

    def __init__(self, source: str, problems: list[str]) -> None:
        self.problems = problems
        super().__init__(f"{source}: " + "; ".join(problems))


@dataclass(frozen=True)
class StartPose:
    x: float
    y: float
    heading_deg: float = 0.0


@dataclass(frozen=True)
class Assignment:
    name: str
    course: str
    title: str
    map_name: str
    robot: str
    time_limit: float
    episodes: int
    seeds: list[int]
    starts: list[StartPose]
    opens: float
    deadline: float
    late: str  # "refuse" or "penalty"
    penalty_per_day: float
    quota: int
    hidden: bool  # the leaderboard hidden from students until the deadline
    score_name: str
    unit: str
    order: str  # "higher" or "lower" is better
    rule: str
    zones: list[dict[str, Any]] = field(default_factory=list)
    # The teacher's grader function (docs/COURSES.md): its file's name and text, kept here.
    grader_file: str = ""
    grader_source: str = ""
    grader_seconds: float = GRADER_SECONDS
    # A real-robot attempt after the simulated episodes (docs/COURSES.md): "" for none.
    real_arena: str = ""
    real_robot: str = ""
    real_time_limit: float = 0.0
    real_after: str = "simulation-passed"  # or "always"
    # Each episode's visibility to its student (VISIBILITIES); empty: every episode "now".
    visibility: list[str] = field(default_factory=list)

    @property
    def score(self) -> Rule:
        return parse_rule(self.rule)

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> Assignment:
        data = json.loads(text)
        data["starts"] = [StartPose(**s) for s in data["starts"]]
        return cls(**data)

    def start(self, episode: int) -> StartPose:
        return self.starts[episode % len(self.starts)]

    def shown_after(self, episode: int, now: float, released_at: float | None) -> str:
        """ "" if the student sees ``episode``'s result now, else when they will (their words)."""
        when = self.visibility[episode] if episode < len(self.visibility) else "now"
        if when == "after_deadline" and now < self.deadline:
            due = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(self.deadline))
            return f"shown after the deadline, {due}"
        if when == "after_release" and released_at is None:
            return "shown when your teacher releases the results"
        return ""

    def better(self, a: float, b: float) -> bool:
        return a > b if self.order == "higher" else a < b


def _time(value: Any) -> float:
    if isinstance(value, dt.datetime):
        if value.tzinfo is None:
            value = value.replace(tzinfo=dt.UTC)
        return value.timestamp()
    if isinstance(value, dt.date):
        return dt.datetime(value.year, value.month, value.day, tzinfo=dt.UTC).timestamp()
    if isinstance(value, str):
        parsed = dt.datetime.fromisoformat(value.replace("Z", "+00:00"))
        return _time(parsed)
    raise ValueError("a date and time, e.g. 2026-12-01T18:00:00Z")


def parse_assignment(
    raw: bytes, source: str, maps_dir: Path, base: Path | None = None
) -> tuple[Assignment, str]:
    """The checked assignment and its map (JSON, the assignment's zones added)."""
    if len(raw) > MAX_FILE_BYTES:
        raise AssignmentError(source, [f"the file is over {MAX_FILE_BYTES // 1024} KiB"])
    try:
        data = load_toml(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise AssignmentError(source, ["the file is not UTF-8 text"]) from None
    except tomllib.TOMLDecodeError as exc:
        raise AssignmentError(source, [f"not TOML: {exc}"]) from None
    problems: list[str] = []
    known = {
        "name", "course", "title", "map", "robot", "time_limit", "episodes", "seeds",
        "start", "opens", "deadline", "late", "quota", "hide_until_deadline", "zones",
        "score", "grader", "grader_time_limit", "real", "visibility",
    }  # fmt: skip
    for key in sorted(set(data) - known):
        problems.append(f"{key}: unknown field (one of {', '.join(sorted(known))})")

    def ident(key: str) -> str:
        value = data.get(key)
        if not isinstance(value, str) or not is_ident(value):
            problems.append(f"{key}: required, a name of letters, digits, '_', '-', '.'")
            return "x"
        return value

    def number(key: str, low: float, high: float, default: float | None = None) -> float:
        value = data.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int | float):
            problems.append(f"{key}: required, a number from {low:g} to {high:g}")
            return low
        if not (low <= value <= high) or not math.isfinite(value):
            problems.append(f"{key}: {value} is not within {low:g}..{high:g}")
            return low
        return float(value)

    name, course, robot = ident("name"), ident("course"), ident("robot")
    title = str(data.get("title", name))[:200]
    time_limit = number("time_limit", 0.5, MAX_EPISODE_S)
    episodes = int(number("episodes", 1, MAX_EPISODES, 1))
    seeds = data.get("seeds", list(range(1, episodes + 1)))
    if not (isinstance(seeds, list) and all(type(s) is int for s in seeds)):
        problems.append("seeds: a list of whole numbers")
        seeds = list(range(1, episodes + 1))
    elif len(seeds) != episodes:
        problems.append(f"seeds: {len(seeds)} seeds for {episodes} episodes")
    quota = int(number("quota", 1, MAX_QUOTA, 10))
    opens = deadline = 0.0
    for key in ("opens", "deadline"):
        try:
            value = _time(data.get(key, "1970-01-01T00:00:00Z" if key == "opens" else None))
        except ValueError as exc:
            problems.append(f"{key}: {exc}")
            continue
        if key == "opens":
            opens = value
        else:
            deadline = value
    if deadline and opens and deadline <= opens:
        problems.append("deadline: before the opening")
    late, penalty = "refuse", 0.0
    late_value = data.get("late", "refuse")
    if isinstance(late_value, dict) and set(late_value) == {"penalty_per_day"}:
        p = late_value["penalty_per_day"]
        if isinstance(p, int | float) and not isinstance(p, bool) and 0 <= p <= 1e6:
            late, penalty = "penalty", float(p)
        else:
            problems.append("late.penalty_per_day: a number ≥ 0 (score points taken per day)")
    elif late_value != "refuse":
        problems.append('late: "refuse", or { penalty_per_day = N }')
    visibility = _visibility(data.get("visibility", "now"), episodes, problems)
    hidden = data.get("hide_until_deadline", False)
    if not isinstance(hidden, bool):
        problems.append("hide_until_deadline: true or false")
        hidden = False
    starts = _starts(data.get("start"), problems)
    zones = data.get("zones", [])
    if not isinstance(zones, list) or not all(isinstance(z, dict) for z in zones):
        problems.append("zones: a list of tables ([[zones]]), as a map's zones")
        zones = []
    score = data.get("score")
    rule: Rule | None = None
    score_name = unit = order = ""
    if not isinstance(score, dict):
        problems.append('score: required, a table: name, unit, order, rule = "..."')
    else:
        for key in sorted(set(score) - {"name", "unit", "order", "rule"}):
            problems.append(f"score.{key}: unknown field (name, unit, order, rule)")
        score_name = str(score.get("name", "score"))[:64]
        unit = str(score.get("unit", ""))[:32]
        order = score.get("order", "higher")
        if order not in ("higher", "lower"):
            problems.append('score.order: "higher" or "lower" (which is better)')
        try:
            rule = parse_rule(score.get("rule", ""))
        except RuleError as exc:
            problems.append(f"score.rule: {exc}")
    grader_file, grader_source = _grader(data.get("grader"), base, problems)
    grader_seconds = number("grader_time_limit", 1, MAX_GRADER_SECONDS, GRADER_SECONDS)
    if rule is not None and rule.metrics and not grader_file and "grader" not in data:
        problems.append(
            f"score.rule: reads metric({sorted(rule.metrics)[0]!r}), but the assignment names "
            'no grader = "file.py" to compute it'
        )
    real = _real(data.get("real"), problems)
    map_text = ""
    map_name = str(data.get("map", ""))
    if not map_name:
        problems.append("map: required, a map of maps/ (e.g. empty) or a .json file")
    elif not problems:
        map_text = _map(map_name, zones, robot, starts, rule, maps_dir, base, problems)
    if problems:
        raise AssignmentError(source, problems)
    assert rule is not None
    assignment = Assignment(
        name=name,
        course=course,
        title=title,
        map_name=map_name,
        robot=robot,
        time_limit=time_limit,
        episodes=episodes,
        seeds=list(seeds),
        starts=starts,
        opens=opens,
        deadline=deadline,
        late=late,
        penalty_per_day=penalty,
        quota=quota,
        hidden=hidden,
        score_name=score_name,
        unit=unit,
        order=str(order),
        rule=rule.text,
        zones=list(zones),
        grader_file=grader_file,
        grader_source=grader_source,
        grader_seconds=grader_seconds,
        real_arena=real[0],
        real_robot=real[1],
        real_time_limit=real[2],
        real_after=real[3],
        visibility=visibility,
    )
    return assignment, map_text


def _visibility(value: Any, episodes: int, problems: list[str]) -> list[str]:
    """Each episode's visibility: one for all ("after_release"), or a list, one per episode."""
    said = f"visibility: one of {', '.join(VISIBILITIES)}, or a list of them, one per episode"
    values = [value] * episodes if isinstance(value, str) else value
    if not isinstance(values, list) or any(v not in VISIBILITIES for v in values):
        problems.append(said)
        return []
    if len(values) != episodes:
        problems.append(f"visibility: {len(values)} value(s) for {episodes} episode(s)")
        return []
    return [] if all(v == "now" for v in values) else [str(v) for v in values]


def _real(value: Any, problems: list[str]) -> tuple[str, str, float, str]:
    """The [real] table: arena (an agent context), robot, time_limit, after."""
    if value is None:
        return "", "", 0.0, "simulation-passed"
    if not isinstance(value, dict):
        problems.append('real: a table: arena = "...", robot = "...", time_limit, after')
        return "", "", 0.0, "simulation-passed"
    for key in sorted(set(value) - {"arena", "robot", "time_limit", "after"}):
        problems.append(f"real.{key}: unknown field (arena, robot, time_limit, after)")
    arena, robot = value.get("arena"), value.get("robot")
    for key, v in (("arena", arena), ("robot", robot)):
        if not isinstance(v, str) or not is_ident(v):
            problems.append(f"real.{key}: required, a name (the real arena's agent context, robot)")
    limit = value.get("time_limit", 10.0)
    if isinstance(limit, bool) or not isinstance(limit, int | float) or not 1 <= limit <= 300:
        problems.append("real.time_limit: a number of seconds from 1 to 300")
        limit = 10.0
    after = value.get("after", "simulation-passed")
    if after not in ("simulation-passed", "always"):
        problems.append('real.after: "simulation-passed" (the default) or "always"')
    return str(arena), str(robot), float(limit), str(after)


def _grader(value: Any, base: Path | None, problems: list[str]) -> tuple[str, str]:
    """The grader file's name and text, checked: it exists, parses, and defines grade()."""
    if value is None:
        return "", ""
    if not isinstance(value, str) or not value.endswith(".py") or "/" in value or "\\" in value:
        problems.append('grader: a Python file beside the assignment, e.g. grader = "g.py"')
        return "", ""
    path = (base or Path.cwd()) / value
    try:
        raw = path.read_bytes()
    except OSError as exc:
        problems.append(f"grader: cannot read {value} ({exc.strerror or exc})")
        return "", ""
    if len(raw) > MAX_FILE_BYTES:
        problems.append(f"grader: {value} is over {MAX_FILE_BYTES // 1024} KiB")
        return "", ""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        problems.append(f"grader: {value} is not UTF-8 text (byte {exc.start})")
        return "", ""
    try:
        tree = ast.parse(text, filename=value)
    except SyntaxError as exc:
        problems.append(f"grader: {value}, line {exc.lineno}: syntax error: {exc.msg}")
        return "", ""
    grade = [
        node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == "grade"
    ]
    if not grade:
        problems.append(f"grader: {value} defines no grade(episode) function at its top level")
        return "", ""
    args = grade[-1].args
    if len(args.posonlyargs) + len(args.args) < 1 and args.vararg is None:
        problems.append(f"grader: {value}, line {grade[-1].lineno}: grade() takes the episode")
        return "", ""
    return value, text


def _starts(value: Any, problems: list[str]) -> list[StartPose]:
    if not isinstance(value, list) or not value:
        problems.append("start: required, one or more [[start]] tables: x, y, heading_deg")
        return [StartPose(0, 0)]
    out = []
    for i, s in enumerate(value):
        try:
            if not isinstance(s, dict) or set(s) - {"x", "y", "heading_deg"}:
                raise TypeError
            pose = StartPose(float(s["x"]), float(s["y"]), float(s.get("heading_deg", 0.0)))
            if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.heading_deg)):
                raise TypeError
            out.append(pose)
        except (KeyError, TypeError, ValueError):
            problems.append(f"start[{i}]: x, y (mm) and optionally heading_deg, numbers")
    return out or [StartPose(0, 0)]


def _map(
    name: str,
    zones: list[dict[str, Any]],
    robot: str,
    starts: list[StartPose],
    rule: Rule | None,
    maps_dir: Path,
    base: Path | None,
    problems: list[str],
) -> str:
    """The map's JSON with the zones added, checked by building its world once."""
    try:
        path = (
            (base or Path.cwd()) / name if name.endswith(".json") else maps.map_path(maps_dir, name)
        )
        raw = path.read_text(encoding="utf-8")
        data = maps.parse_map(raw, source=str(path))
    except (OSError, ValueError) as exc:
        problems.append(f"map: {name}: {exc}")
        return ""
    data.setdefault("zones", [])
    data["zones"] = list(data["zones"]) + zones
    text = json.dumps(data)
    if len(text) > MAX_MAP_BYTES:
        problems.append(f"map: over {MAX_MAP_BYTES // 1024} KiB")
        return ""
    try:
        world = maps.build_world(data, name="check", source=f"map {name} with the zones")
    except ValueError as exc:
        problems.append(f"zones or map: {exc}")
        return ""
    if robot not in [a.id for a in world.agents]:
        ids = ", ".join(a.id for a in world.agents) or "none"
        problems.append(f"robot: the map {name} has no robot {robot} (it has {ids})")
    for i, s in enumerate(starts):
        if not (0 < s.x < world.width and 0 < s.y < world.height):
            problems.append(f"start[{i}]: ({s.x:g}, {s.y:g}) is outside the arena")
    for zone in sorted(rule.zones if rule else ()):
        if zone not in world.zones:
            have = ", ".join(sorted(world.zones)) or "none"
            problems.append(f"score.rule: names zone {zone!r}, which the map lacks (has {have})")
    return text
