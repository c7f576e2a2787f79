"""What a student or a teacher may read of submissions: the list, and each episode's replay.

A student reads their own submissions, each episode as its visibility allows
(services/grader/visibility.py) and saying whether its recording is still kept;
a teacher reads anyone's, whole. A graded episode's recording (services/grader/
episode_recordings.py) goes to its student once the episode is shown, or to a
teacher; another student's submission is answered as if it did not exist.
"""

from __future__ import annotations

import time

import msgspec

from common.messages import EpisodeReplayGet, RecordingChunk, SubmissionInfo, SubmissionList
from common.service import RequestError
from services.grader.assignment import Assignment
from services.grader.episode_recordings import EpisodeRecordings
from services.grader.grading_db import GradingStore
from services.grader.visibility import as_student_sees

MAX_LISTED = 500


class ResultsDesk:
    def __init__(self, store: GradingStore, recordings: EpisodeRecordings) -> None:
        self.store = store
        self.recordings = recordings

    def submissions(
        self, a: Assignment, user: str | None, submission: str | None, teacher: bool
    ) -> SubmissionList:
        found = [self._flagged(s) for s in self.store.submissions(a.name, user, submission)]
        found = found[-MAX_LISTED:]
        if not teacher:
            now, released = time.time(), self.store.released_at(a.name)
            found = [as_student_sees(s, a, now, released) for s in found]
        return SubmissionList(submissions=found)

    def _flagged(self, sub: SubmissionInfo) -> SubmissionInfo:
        """``sub`` with each episode saying whether its recording is still kept to replay."""
        episodes = [
            msgspec.structs.replace(
                e,
                replay=not e.real
                and self.recordings.has(sub.assignment, sub.user, sub.submission, e.episode),
            )
            for e in sub.episodes
        ]
        return msgspec.structs.replace(sub, episodes=episodes)

    def episode(
        self, user: str, teacher: bool, a: Assignment, request: EpisodeReplayGet
    ) -> RecordingChunk:
        """A chunk of a graded episode's recording: the submission's student, or a teacher."""
        found = self.store.submissions(a.name, None, request.submission)
        if not found or (found[0].user != user and not teacher):
            # Another student's submission is answered as if it did not exist.
            raise RequestError("not_found", f"you have no submission {request.submission}")
        owner = found[0].user
        when = a.shown_after(request.episode, time.time(), self.store.released_at(a.name))
        if when and not teacher:
            raise RequestError("forbidden", f"episode {request.episode} is {when}")
        if not self.recordings.has(a.name, owner, request.submission, request.episode):
            raise RequestError(
                "not_found",
                f"episode {request.episode} of {request.submission} has no replay kept (the "
                f"newest {self.recordings.keep} submissions of each student keep theirs)",
            )
        try:
            return self.recordings.chunk(
                a.name, owner, request.submission, request.episode, request.offset
            )
        except OSError as exc:
            raise RequestError("not_found", f"the replay could not be read: {exc}") from None
