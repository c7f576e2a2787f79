"""The grader's queue: round-robin by student, lab re-runs first (pure, thread-safe).

One student's ten submissions do not starve the others: each turn takes the
oldest submission of the next student in the rotation, so a student who
submitted once waits at most one submission of each other student. A job
the lab failed goes to the head (it has waited its turn already).
"""

from __future__ import annotations

import threading
from collections import OrderedDict, deque
from typing import Generic, TypeVar

T = TypeVar("T")


class FairQueue(Generic[T]):
    def __init__(self) -> None:
        self._head: deque[tuple[str, T]] = deque()
        self._by_user: OrderedDict[str, deque[T]] = OrderedDict()  # rotation order
        self._cond = threading.Condition()
        self._closed = False

    def put(self, user: str, job: T) -> int:
        """Queue ``job``; its place (1 = next) if nobody else submits meanwhile."""
        with self._cond:
            jobs = self._by_user.setdefault(user, deque())
            jobs.append(job)
            self._cond.notify()
            return self._place(user, len(jobs))

    def put_first(self, user: str, job: T) -> None:
        with self._cond:
            self._head.append((user, job))
            self._cond.notify()

    def _place(self, user: str, nth: int) -> int:
        """Where the ``nth`` job of ``user`` stands: each turn of the rotation takes one job
        of each student who still has one, in rotation order."""
        place, before = len(self._head), True
        for other, jobs in self._by_user.items():
            if other == user:
                place += nth
                before = False
            else:
                place += min(len(jobs), nth if before else nth - 1)
        return place

    def order(self) -> list[tuple[str, T]]:
        """Every queued (user, job) in the order :meth:`get` will take them (if nobody else
        submits meanwhile): the head, then round by round one job of each student still
        holding one, in rotation order (a student moved to the end keeps their place
        relative to the others)."""
        with self._cond:
            out = list(self._head)
            rounds = max((len(jobs) for jobs in self._by_user.values()), default=0)
            for k in range(rounds):
                out += [(u, jobs[k]) for u, jobs in self._by_user.items() if k < len(jobs)]
            return out

    def get(self, timeout: float | None = None) -> tuple[str, T] | None:
        """The next (user, job), or None when closed or on timeout."""
        with self._cond:
            while not self._head and not self._by_user:
                if self._closed or not self._cond.wait(timeout):
                    return None
            if self._closed:
                return None
            if self._head:
                return self._head.popleft()
            user, jobs = next(iter(self._by_user.items()))
            job = jobs.popleft()
            del self._by_user[user]
            if jobs:
                self._by_user[user] = jobs  # to the end of the rotation
            return user, job

    def remove_user(self, user: str) -> list[T]:
        """Take every queued job of ``user`` out (a banned account's): those jobs."""
        with self._cond:
            gone = list(self._by_user.pop(user, deque()))
            kept = deque((u, job) for u, job in self._head if u != user)
            gone += [job for u, job in self._head if u == user]
            self._head = kept
            return gone

    def __len__(self) -> int:
        with self._cond:
            return len(self._head) + sum(len(j) for j in self._by_user.values())

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
