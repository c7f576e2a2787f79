"""The grader's queue depth, put every few seconds on ``grader/<name>/queue``.

Submissions queued and those being graded: what a cluster's host scales the
runners on (services/lab/kube/runner_scale.py). Put, not asked: a reader that
missed one has the next, and the grader answers nobody for it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import zenoh

from common import keys
from common.messages import GraderQueue, encode
from common.worker import Worker

QUEUE_PERIOD_S = 5.0  # how often the depth is put


class QueueDepth:
    """Counts the submissions being graded; puts the depth with the queue's length."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        grader: str,
        queued: Callable[[], int],
        period: float = QUEUE_PERIOD_S,
    ) -> None:
        self.session = session
        self.key = keys.grader_queue(realm, grader)
        self.grader = grader
        self.queued = queued
        self.period = period
        self.log = logging.getLogger(f"grader.{grader}.queue")
        self._running = 0
        self._lock = threading.Lock()
        self._worker = Worker(self._say, "queue-depth")

    @contextmanager
    def grading(self) -> Iterator[None]:
        """While one submission is graded."""
        with self._lock:
            self._running += 1
        try:
            yield
        finally:
            with self._lock:
                self._running -= 1

    def now(self) -> GraderQueue:
        with self._lock:
            running = self._running
        return GraderQueue(
            grader=self.grader, queued=self.queued(), running=running, at=time.time()
        )

    def start(self) -> None:
        self._worker.start()

    def stop(self, timeout: float = 2.0) -> None:
        self._worker.stop(timeout)

    def _say(self) -> None:
        while not self._worker.stopping.is_set():
            try:
                self.session.put(self.key, encode(self.now()))
            except Exception as exc:  # the session closing: the stop comes next
                self.log.warning("could not put the queue's depth: %s", exc)
            self._worker.wait(self.period)
