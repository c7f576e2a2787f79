"""What a student may see of their own submissions, by each episode's visibility.

An assignment gives each episode (each check) a visibility: ``now``,
``after_deadline`` or ``after_release`` (services/grader/assignment.py). Until an
episode's time comes, its student reads that it exists and when it will be
shown, not its score, how it ended, what it printed or its replay; and the mean
and min, which would give it away, wait for every episode. The leaderboard,
made of those means, is hidden from students for as long. Teachers see all.
"""

from __future__ import annotations

import msgspec

from common.messages import EpisodeResult, SubmissionInfo
from services.grader.assignment import Assignment


def as_student_sees(
    sub: SubmissionInfo, a: Assignment, now: float, released_at: float | None
) -> SubmissionInfo:
    """``sub`` with each episode not shown yet reduced to when it will be."""
    episodes: list[EpisodeResult] = []
    withheld = ""
    for e in sub.episodes:
        when = "" if e.real else a.shown_after(e.episode, now, released_at)
        if when and e.cause != "lab":
            withheld = when
            e = EpisodeResult(episode=e.episode, seed=e.seed, cause="hidden", detail=when)
        episodes.append(e)
    if not withheld:
        return sub
    return msgspec.structs.replace(
        sub,
        episodes=episodes,
        mean=None,
        min=None,
        message=f"graded; the mean is {withheld}, with every episode"[:256]
        if sub.status == "graded"
        else sub.message,
    )


def board_hidden_until(a: Assignment, now: float, released_at: float | None) -> str:
    """Why students may not see the leaderboard yet ("" if they may)."""
    for n in range(a.episodes):
        when = a.shown_after(n, now, released_at)
        if when:
            return when
    return ""
