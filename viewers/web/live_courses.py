"""A live connection's courses: the grader's calls and feeds, the part it holds
(``connection.courses``, as ``connection.admin`` holds its account administration)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from common.client import lab_client as lab
from common.client.grader_client import GraderClient, submitted_words
from common.messages.grading import (
    AssignmentInfo,
    ClassTable,
    GradingChanged,
    Leaderboard,
    Standings,
    SubmissionInfo,
)
from viewers.web.fanout import Fanout


class LiveCourses:
    """My courses in a live lab; ``call`` maps the lab's errors to the page's words."""

    def __init__(self, client: lab.LabClient, call: Callable[[Callable[[], Any]], Any]) -> None:
        self._grader = GraderClient(client)
        self._call = call
        # The grader's feeds, one subscription each for all panels (fanout.py: why).
        grader = self._grader
        self._standings: Fanout[Standings] = Fanout(lambda f: grader.watch_standings(None, f))
        self._grading: Fanout[GradingChanged] = Fanout(grader.watch_changes)

    def assignments(self) -> list[AssignmentInfo]:
        return list(self._call(self._grader.assignments))

    def submit(self, assignment: str, filename: str, source: bytes) -> str:
        ok = self._call(lambda: self._grader.submit(assignment, source, filename))
        return submitted_words(ok)

    def submissions(self, assignment: str) -> list[SubmissionInfo]:
        return list(self._call(lambda: self._grader.submissions(assignment)))

    def leaderboard(self, assignment: str) -> Leaderboard:
        return self._call(lambda: self._grader.leaderboard(assignment))

    def fetch_episode(self, assignment: str, submission: str, episode: int, dest: Path) -> Path:
        grader = self._grader
        return self._call(lambda: grader.fetch_episode(assignment, submission, episode, dest))

    def watch_standings(self, on_standings: Callable[[Standings], None]) -> Callable[[], None]:
        return self._call(lambda: self._standings.add(on_standings))

    def watch_grading(self, on_change: Callable[[GradingChanged], None]) -> Callable[[], None]:
        return self._call(lambda: self._grading.add(on_change))

    def class_tables(self) -> list[ClassTable]:
        return list(self._call(self._grader.class_tables))

    def close(self) -> None:
        self._standings.close()
        self._grading.close()
