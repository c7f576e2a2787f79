"""One subscription shared by a connection's panels: each message to every listener.

A lab connection's client has one verifier, whose replay window refuses the
second delivery of a message it has opened: two panels each subscribing to the
grader's changes (an arena tab's Course and Class folders, or two arena tabs)
would see the second one refused as a replay. So the connection subscribes once
and hands each message to every listener.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

M = TypeVar("M")
log = logging.getLogger("wart.viewer")


class Fanout(Generic[M]):
    def __init__(self, subscribe: Callable[[Callable[[M], None]], Callable[[], None]]) -> None:
        """``subscribe(deliver)`` starts the one subscription and returns its stopper."""
        self._subscribe = subscribe
        self._listeners: list[Callable[[M], None]] = []
        self._stop: Callable[[], None] | None = None
        self._lock = threading.Lock()

    def add(self, listener: Callable[[M], None]) -> Callable[[], None]:
        """Call ``listener`` with each message from now on; returns: stop calling it. The first
        listener starts the subscription (its error, e.g. a LabError, comes out of here)."""
        with self._lock:
            if self._stop is None:
                self._stop = self._subscribe(self._deliver)
            self._listeners.append(listener)

        def remove() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return remove

    def _deliver(self, message: M) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener(message)
            except Exception:  # one panel's bug must not starve the others
                log.exception("a listener of %s failed", type(message).__name__)

    def close(self) -> None:
        with self._lock:
            stop, self._stop = self._stop, None
            self._listeners.clear()
        if stop is not None:
            stop()
