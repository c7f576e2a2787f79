"""An assignment's leaderboard: each student's best score, ranked as each reader may see it."""

from __future__ import annotations

import time

from common.messages import Leaderboard, LeaderEntry
from services.grader.assignment import Assignment
from services.grader.grading_db import GradingStore
from services.grader.visibility import board_hidden_until


def _shown(name: str, pseudonym: str | None, teacher: bool) -> str:
    """A student's name on a leaderboard: their pseudonym, which teachers see beside the name."""
    if not pseudonym:
        return name
    return f"{name} (as {pseudonym})" if teacher else pseudonym


def leaderboard(store: GradingStore, a: Assignment, teacher: bool) -> Leaderboard:
    """Best per student in the assignment's order; hidden from students until the deadline
    where the assignment says so, and while an episode's result is not shown to its student
    (a teacher always sees it, names beside pseudonyms)."""
    now = time.time()
    until = board_hidden_until(a, now, store.released_at(a.name))
    hidden = bool(until) or (a.hidden and now < a.deadline)
    entries: list[LeaderEntry] = []
    if teacher or not hidden:
        names = store.display_names(a.course)
        chosen = store.pseudonyms(a.course)
        best = store.best(a.name, higher=a.order == "higher")
        best.sort(key=lambda row: (-row[1] if a.order == "higher" else row[1], row[3]))
        rank, previous = 0, None
        for i, (user, score, sub, at) in enumerate(best):
            if score != previous:
                rank, previous = i + 1, score
            entries.append(
                LeaderEntry(
                    rank=rank,
                    name=_shown(names.get(user) or user, chosen.get(user), teacher),
                    score=round(score, 4),
                    submission=sub,
                    at=at,
                    real=store.real_score(sub) if a.real_arena else None,
                )
            )
    return Leaderboard(
        assignment=a.name,
        score_name=a.score_name,
        unit=a.unit,
        order=a.order,  # type: ignore[arg-type]
        hidden=hidden,
        deadline=a.deadline,
        hidden_until=until,
        entries=entries,
    )
