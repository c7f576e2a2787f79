"""A part's background thread: started once, stopped by one call that wakes and joins it.

A recorder, a pump or a poller holds a ``Worker`` and writes its loop against
``worker.stopping``; stopping sets it (and whatever else the loop sleeps on),
joins the thread, and says so in the log if the loop did not end in time: a
thread stuck in a call is a thing an operator wants named, not a silent hang
at shutdown.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)


class Worker:
    """One daemon thread running ``loop``; ``loop`` returns once ``stopping`` is set.

    ``wake`` is called by ``stop()`` after ``stopping`` is set, for a loop that sleeps
    on something else too (a condition, a second event)."""

    def __init__(
        self, loop: Callable[[], None], name: str, *, wake: Callable[[], None] | None = None
    ) -> None:
        self.name = name
        self.stopping = threading.Event()
        self._loop = loop
        self._wake = wake
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        """Start the thread (again, after a stop); nothing if it runs."""
        if self.running:
            return
        self.stopping.clear()
        self._thread = threading.Thread(target=self._loop, name=self.name, daemon=True)
        self._thread.start()

    def stop(self, timeout: float) -> bool:
        """Ask the loop to end and wait up to ``timeout`` s; whether it ended."""
        self.stopping.set()
        thread, self._thread = self._thread, None
        if thread is None:
            return True  # never started: nothing to wake (an http server's shutdown would hang)
        if self._wake is not None:
            self._wake()
        if thread is threading.current_thread():
            return True
        thread.join(timeout)
        if thread.is_alive():
            log.warning("thread %s did not end within %.1f s of its stop", self.name, timeout)
            return False
        return True

    def wait(self, seconds: float) -> bool:
        """Sleep up to ``seconds``; True as soon as the worker is stopping."""
        return self.stopping.wait(seconds)
