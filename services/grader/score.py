"""An assignment's score rule: a tiny arithmetic over an episode's events, never eval'd.

The teacher writes one expression, e.g.::

    100 * reached("goal") - 5 * collisions() - time_to("goal")

It is parsed with Python's ``ast`` and only this grammar is accepted (anything
else is refused with what and where, before the assignment is stored):

- numbers; ``+ - * /``, unary ``-``; parentheses;
- ``min(a, b, ...)``, ``max(a, b, ...)``, ``abs(a)``;
- the events of an episode (``services/runner/episode.py`` records them):
  ``reached("zone")`` 1 if the robot's centre entered the zone, else 0;
  ``time_to("zone")`` the simulated s it first did (the time limit if never);
  ``delivered()`` objects lying in a nest zone at some point, ``delivered("id")`` 1/0;
  ``collisions()`` new contacts with walls, obstacles and robots (pushing
  objects is not one); ``collisions("wall"|"obstacle"|"robot"|"object")``;
  ``time()`` the simulated s the episode ran; ``distance()`` metres driven;
  ``metric("name")`` a number the assignment's grader function returned for
  the episode (services/runner/grader_run.py); only with a grader.

Division by zero scores 0 for that term's quotient rather than failing the run.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable
from dataclasses import dataclass

from common.messages import EpisodeReport
from common.messages.grading import MAX_TERMS

MAX_RULE_CHARS = 500
MAX_NODES = 200
COLLISION_KINDS = ("wall", "obstacle", "robot", "object")
# name -> (arguments allowed: 0, 1 or (0 or 1), whether the argument must be given)
_EVENTS: dict[str, tuple[int, int]] = {
    "reached": (1, 1),
    "time_to": (1, 1),
    "delivered": (0, 1),
    "collisions": (0, 1),
    "time": (0, 0),
    "distance": (0, 0),
    "metric": (1, 1),
}
_MATH: dict[str, Callable[..., float]] = {"min": min, "max": max, "abs": abs}


_PLAIN = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Add, ast.Sub, ast.Mult, ast.Div)
_PLAIN += (ast.USub, ast.UAdd, ast.Load)  # type: ignore[assignment]


class RuleError(ValueError):
    """The rule is not in the grammar; the message says what and where."""


class MissingMetric(RuleError):
    """The rule reads a metric the grader function did not return (the teacher's fault)."""


@dataclass(frozen=True)
class Rule:
    text: str
    tree: ast.expr
    zones: frozenset[str]  # the zones it names (the assignment must have them)
    metrics: frozenset[str] = frozenset()  # the grader's metrics it reads

    def evaluate(self, report: EpisodeReport, time_limit: float) -> float:
        value = _eval(self.tree, report, time_limit)
        return value if math.isfinite(value) else 0.0

    def terms(self, report: EpisodeReport, time_limit: float) -> list[tuple[str, float]]:
        """The rule's top-level terms as written, each with its signed value; they add up to
        :meth:`evaluate` (``100 * reached("goal") - 5 * collisions()``: two terms)."""
        found: list[tuple[str, float]] = []
        _split(self.text, self.tree, 1.0, found, report, time_limit)
        if len(found) > MAX_TERMS:  # a long sum: the first ones, then the rest as one
            rest = sum(v for _, v in found[MAX_TERMS - 1 :])
            found = [*found[: MAX_TERMS - 1], ("the other terms", rest)]
        return [(text[:256], v if math.isfinite(v) else 0.0) for text, v in found]


def judge(
    rule: Rule, report: EpisodeReport, time_limit: float, grader_file: str
) -> tuple[float, str]:
    """The rule's score of an episode and the teacher's error ("" if none, else the score is
    0): their grader function's, or a metric the rule reads that it did not give."""
    if report.grader_error:
        return 0.0, report.grader_error
    try:
        return rule.evaluate(report, time_limit), ""
    except MissingMetric as exc:
        return 0.0, f"{grader_file}: {exc}"


def parse_rule(text: str) -> Rule:
    if not isinstance(text, str) or not text.strip():
        raise RuleError("the rule is empty")
    if len(text) > MAX_RULE_CHARS:
        raise RuleError(f"the rule is longer than {MAX_RULE_CHARS} characters")
    try:
        tree = ast.parse(text.strip(), mode="eval")
    except SyntaxError as exc:
        raise RuleError(f"not an expression (column {exc.offset}): {exc.msg}") from None
    nodes = list(ast.walk(tree))
    if len(nodes) > MAX_NODES:
        raise RuleError(f"the rule is too long ({len(nodes)} parts; at most {MAX_NODES})")
    zones: set[str] = set()
    for node in nodes:
        _check(node, zones)
    named = frozenset(
        n.args[0].value  # type: ignore[attr-defined]  # _check_call let constants only
        for n in nodes
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "metric"
    )
    return Rule(text=text.strip(), tree=tree.body, zones=frozenset(zones), metrics=named)


def _where(node: ast.AST) -> str:
    return f"column {getattr(node, 'col_offset', 0) + 1}"


def _check(node: ast.AST, zones: set[str]) -> None:
    if isinstance(node, _PLAIN):
        return
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, int | float | str):
            raise RuleError(f"{_where(node)}: only numbers and quoted names")
        return
    if isinstance(node, ast.Name):
        if node.id in _EVENTS or node.id in _MATH:
            return  # the function called (checked at the Call)
        raise RuleError(
            f"{_where(node)}: unknown name {node.id!r}: use {', '.join(_EVENTS)} "
            f"(called, e.g. time()), or {', '.join(_MATH)}"
        )
    if isinstance(node, ast.Call):
        _check_call(node, zones)
        return
    raise RuleError(f"{_where(node)}: {type(node).__name__} is not allowed in a score rule")


def _check_call(node: ast.Call, zones: set[str]) -> None:
    if not isinstance(node.func, ast.Name) or node.keywords:
        raise RuleError(f"{_where(node)}: call a function by its name, without keywords")
    name = node.func.id
    if name in _MATH:
        if not node.args or (name == "abs" and len(node.args) != 1):
            raise RuleError(f"{_where(node)}: {name}() needs arguments")
        for arg in node.args:
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                raise RuleError(f"{_where(arg)}: {name}() takes numbers")
        return
    if name not in _EVENTS:
        raise RuleError(f"{_where(node)}: unknown function {name}()")
    low, high = _EVENTS[name]
    if not low <= len(node.args) <= high:
        want = f"{low}" if low == high else f"{low} or {high}"
        raise RuleError(f"{_where(node)}: {name}() takes {want} argument(s)")
    for arg in node.args:
        if not (isinstance(arg, ast.Constant) and isinstance(arg.value, str)):
            raise RuleError(f'{_where(arg)}: {name}() takes a quoted name, e.g. {name}("goal")')
        if name in ("reached", "time_to"):
            zones.add(arg.value)
        if name == "collisions" and arg.value not in COLLISION_KINDS:
            raise RuleError(
                f"{_where(arg)}: collisions() counts one of {', '.join(COLLISION_KINDS)}"
            )


def event(name: str, arg: str | None, report: EpisodeReport, time_limit: float) -> float:
    """One event's value in an episode (the grammar's functions)."""
    if name == "reached":
        return 1.0 if arg in report.reached else 0.0
    if name == "time_to":
        return float(report.reached.get(arg or "", time_limit))
    if name == "delivered":
        if arg is None:
            return float(len(report.delivered))
        return 1.0 if arg in report.delivered else 0.0
    if name == "collisions":
        if arg is None:
            return float(sum(n for k, n in report.collisions.items() if k != "object"))
        return float(report.collisions.get(arg, 0))
    if name == "time":
        return float(report.sim_seconds)
    if name == "distance":
        return float(report.distance_mm) / 1000.0
    if name == "metric":
        if arg not in report.grader_metrics:
            have = ", ".join(sorted(report.grader_metrics)) or "none"
            raise MissingMetric(f"grade() returned no metric {arg!r} (it returned: {have})")
        return float(report.grader_metrics[arg])
    raise RuleError(f"unknown event {name}")


def _split(
    text: str,
    node: ast.expr,
    sign: float,
    out: list[tuple[str, float]],
    report: EpisodeReport,
    limit: float,
) -> None:
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Add | ast.Sub):
        _split(text, node.left, sign, out, report, limit)
        _split(
            text, node.right, sign if isinstance(node.op, ast.Add) else -sign, out, report, limit
        )
        return
    written = ast.get_source_segment(text, node) or ast.unparse(node)
    out.append((("- " if sign < 0 else "") + written, sign * _eval(node, report, limit)))


def _eval(node: ast.expr, report: EpisodeReport, limit: float) -> float:
    if isinstance(node, ast.Constant):
        return float(node.value)  # type: ignore[arg-type]  # parse_rule let numbers only here
    if isinstance(node, ast.UnaryOp):
        value = _eval(node.operand, report, limit)
        return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, ast.BinOp):
        a, b = _eval(node.left, report, limit), _eval(node.right, report, limit)
        if isinstance(node.op, ast.Add):
            return a + b
        if isinstance(node.op, ast.Sub):
            return a - b
        if isinstance(node.op, ast.Mult):
            return a * b
        return a / b if b else 0.0
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
        name = node.func.id
        if name in _MATH:
            return float(_MATH[name](*(_eval(a, report, limit) for a in node.args)))
        arg = node.args[0].value if node.args else None  # type: ignore[attr-defined]
        return event(name, arg, report, limit)
    raise RuleError(f"cannot evaluate {type(node).__name__}")  # parse_rule let it through


def metrics(report: EpisodeReport, zones: list[str], time_limit: float) -> dict[str, float]:
    """The episode's numbers a student sees beside its score."""
    out = {
        "time_s": float(report.sim_seconds),
        "collisions": event("collisions", None, report, time_limit),
        "delivered": float(len(report.delivered)),
        "distance_m": round(report.distance_mm / 1000.0, 3),
    }
    for zone in zones:
        out[f"time_to_{zone}"] = event("time_to", zone, report, time_limit)
    for name, value in sorted(report.grader_metrics.items()):
        out.setdefault(name, value)  # the grader's own numbers, beside ours
    return out
