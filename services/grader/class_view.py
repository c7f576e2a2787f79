"""The teacher's view of a class: every student of a course, their latest submission, live.

A pure function of what the grading store and the queue hold, so it is tested
without a lab: one row per student of the roster (a student who never
submitted has a row too), the latest submission to any of the course's
assignments with its status and place in the grading queue, the latest graded
score (after the late penalty), and how the last failed run ended: the
student's code (``exception: line 7: ZeroDivisionError ...``) or the lab
(``failed: the lab could not grade it ...``, re-run free).
"""

from __future__ import annotations

import time

from common.messages import ClassRow, ClassTable
from services.grader.grading_db import CourseSubmission

FAILURE_CHARS = 200


def failure_of(sub: CourseSubmission) -> str:
    """How ``sub`` failed, in a line ("" if it did not): an episode's cause, or the lab's."""
    if sub.status == "failed":
        return f"lab: {sub.message}"[:FAILURE_CHARS]
    return sub.failed_episode[:FAILURE_CHARS]


def class_table(
    course: str,
    title: str,
    students: list[tuple[str, str, str]],
    submissions: list[CourseSubmission],
    queued: list[str],
) -> ClassTable:
    """``students``: (user, name, team); ``submissions`` oldest first; ``queued``: the
    submission ids in the order the grader will take them."""
    place = {sub: i + 1 for i, sub in enumerate(queued)}
    latest: dict[str, CourseSubmission] = {}
    graded: dict[str, CourseSubmission] = {}
    failed: dict[str, str] = {}
    count: dict[str, int] = {}
    for sub in submissions:
        latest[sub.user] = sub
        count[sub.user] = count.get(sub.user, 0) + 1
        if sub.status == "graded" and sub.score is not None:
            graded[sub.user] = sub
        why = failure_of(sub)
        if why:
            failed[sub.user] = why
    rows = []
    for user, name, team in students:
        last = latest.get(user)
        best = graded.get(user)
        rows.append(
            ClassRow(
                user=user,
                name=name[:256],
                team=team[:256],
                assignment=last.assignment if last else None,
                submission=last.id if last else None,
                status=last.status if last else None,  # type: ignore[arg-type]
                submitted_at=last.submitted_at if last else None,
                queue_place=place.get(last.id) if last else None,
                score=round(best.score, 4) if best and best.score is not None else None,
                failure=failed.get(user, ""),
                submissions=count.get(user, 0),
            )
        )
    return ClassTable(course=course, title=title[:256], rows=rows, at=time.time())
