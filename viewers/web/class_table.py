"""The model of the page's Class folder: the grader's class table joined with the arena's runs.

Pure functions, tested without a page (tests/unit/viewers/web/test_class_table.py): each
student's row (latest submission, its status and queue place, score, how the
last failure ended) beside their live run on this arena if one runs (robot,
time left, taken over by whom), and the keys a teacher holds turned into
wheel speeds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from common.messages import ClassRow, ClassTable
from viewers.web.adapters import AgentStatus
from viewers.web.text import escape_md

STATUS = {"queued": "queued", "running": "grading", "graded": "graded", "failed": "failed"}
MAX_ROWS = 200  # a class bigger than this is cut (the grader sends up to 5000)

# Keys held → wheel speeds (the Khepera's units; key_driver.py caps them at 20).
# f/b: forward, back; l/r: turn. Forward or back with a turn curves.
FAST, SLOW = 12, 5
KEY_NAMES = {
    "ArrowUp": "f",
    "KeyW": "f",
    "ArrowDown": "b",
    "KeyS": "b",
    "ArrowLeft": "l",
    "KeyA": "l",
    "ArrowRight": "r",
    "KeyD": "r",
}


@dataclass(frozen=True)
class LiveRun:
    agent: str
    left_s: float | None
    taken_by: str | None


def live_runs(rows: list[AgentStatus]) -> dict[str, LiveRun]:
    """Who runs a controller on which robot of the arena now (the holder of each robot)."""
    runs: dict[str, LiveRun] = {}
    for row in rows:
        if row.holder is not None and row.holder not in runs:
            runs[row.holder] = LiveRun(row.agent, row.slot_left_s, row.taken_by)
    return runs


def speeds_for(held: str) -> tuple[int, int]:
    """Wheel speeds for the held directions ("f", "b", "l", "r" in any order; "" stops).
    Opposite keys cancel; unknown letters are ignored."""
    forward = ("f" in held) - ("b" in held)
    turn = ("r" in held) - ("l" in held)
    if forward == 0:
        return (SLOW * turn, -SLOW * turn)
    base = FAST * forward
    if turn == 0:
        return (base, base)
    # Curving: the inner wheel slower (a turn right while backing still turns right).
    inner = SLOW * forward
    return (base, inner) if turn > 0 else (inner, base)


def parse_keys(value: str) -> str:
    """The page's "held keys, sequence" text (``"fl 17"``) → the held directions; anything
    else (not the page's script) is nothing held: the robot stops."""
    held = value.split(" ", 1)[0] if value else ""
    if len(held) > 4 or not set(held) <= set("fblr"):
        return ""
    return "".join(sorted(set(held)))


class KeyHold:
    """The keys a page holds, and its deadman: nothing heard for ``deadman_s`` while keys are
    held means the page is gone (closed, cut off) and the robot must stop."""

    def __init__(self, deadman_s: float) -> None:
        self.deadman_s = deadman_s
        self.held = ""
        self._heard = 0.0

    def update(self, value: str, now: float) -> tuple[int, int] | None:
        """The page's text at ``now`` (monotonic s): new wheel speeds, or None if the same
        keys are still held (a heartbeat)."""
        held = parse_keys(value)
        self._heard = now
        if held == self.held:
            return None
        self.held = held
        return speeds_for(held)

    def expired(self, now: float) -> bool:
        """True once (then nothing is held) if keys are held and the page went quiet."""
        if self.held and now - self._heard > self.deadman_s:
            self.held = ""
            return True
        return False


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def row_cells(row: ClassRow, run: LiveRun | None) -> list[str]:
    """One student's cells: student, latest, status, queue, score, last failure, live run."""
    who = escape_md(f"{row.name} ({row.user})" if row.name and row.name != row.user else row.user)
    if row.submission is None:
        latest, status = "-", "no submission"
    else:
        when = time.strftime("%H:%M:%S", time.localtime(row.submitted_at or 0))
        latest = f"{escape_md(row.assignment or '')} {when}"
        status = STATUS.get(row.status or "", row.status or "-")
    queue = str(row.queue_place) if row.queue_place else "-"
    failure = escape_md(row.failure) if row.failure else "-"
    if run is None:
        live = "-"
    else:
        left = "" if run.left_s is None else f", {run.left_s:.0f} s left"
        taken = f", taken over by {escape_md(run.taken_by)}" if run.taken_by else ""
        live = f"{escape_md(run.agent)}{left}{taken}"
    return [who, latest, status, queue, _num(row.score), failure, live]


def format_class(tables: list[ClassTable], runs: dict[str, LiveRun]) -> str:
    """The Class folder's tables, one per course I teach."""
    if not tables:
        return "_You teach no course here._"
    out: list[str] = []
    for table in tables:
        out += [
            f"**{escape_md(table.title or table.course)}** ({escape_md(table.course)}): "
            f"{len(table.rows)} student(s)",
            "",
            "| student | latest | status | queue | score | last failure | live run |",
            "| --- | --- | --- | --- | --- | --- | --- |",
        ]
        for row in table.rows[:MAX_ROWS]:
            cells = row_cells(row, runs.get(row.user))
            out.append("| " + " | ".join(cells) + " |")  # each cell escaped (pipes too)
        if len(table.rows) > MAX_ROWS:
            out.append(f"\n_{len(table.rows) - MAX_ROWS} more not shown._")
        out.append("")
    return "\n".join(out).rstrip()


def students(tables: list[ClassTable]) -> tuple[str, ...]:
    """Every student's account in the tables, once, in order."""
    seen: dict[str, None] = {}
    for table in tables:
        for row in table.rows:
            seen.setdefault(row.user, None)
    return tuple(seen)
