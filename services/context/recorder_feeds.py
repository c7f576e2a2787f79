"""What a slot recorder hears, and when.

Some feeds are heard for the recorder's whole life (the world's frames, samples and
commands, the tracked poses); others only while a slot is recorded (a real arena's
camera videos: a camera encodes no video that no one watches). The recorder owns
one :class:`RecorderFeeds` and tells it after each change to its runs.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from typing import Any

import zenoh

Feed = tuple[str, Callable[[zenoh.Sample], None]]  # a key and its callback


class RecorderFeeds:
    def __init__(self, session: zenoh.Session, log: logging.Logger) -> None:
        self.session = session
        self.log = log
        self._always: list[Any] = []
        self._while: list[Any] = []  # declared while a slot is recorded
        self._lock = threading.Lock()

    def hear(self, feeds: Iterable[Feed]) -> None:
        """Subscribe to ``feeds`` until :meth:`close`."""
        with self._lock:
            self._declare(self._always, feeds)

    def hear_while(
        self, recording: Callable[[], bool], feeds: Callable[[], Iterable[Feed]]
    ) -> None:
        """Subscribe to ``feeds()`` while ``recording()``, else drop them.

        Called after each change to the recorder's runs; ``recording`` is asked under
        the lock, so that of two calls racing (a slot starting as another ends) the
        last decides, and it sees both changes.
        """
        with self._lock:
            if recording():
                if not self._while:
                    self._declare(self._while, feeds())
            else:
                self._undeclare(self._while)

    def close(self) -> None:
        with self._lock:
            self._undeclare(self._always)
            self._undeclare(self._while)

    def _declare(self, into: list[Any], feeds: Iterable[Feed]) -> None:
        for key, handler in feeds:
            into.append(self.session.declare_subscriber(key, handler))

    def _undeclare(self, subscribers: list[Any]) -> None:
        for sub in subscribers:
            try:
                sub.undeclare()
            except Exception as exc:  # the session closing first
                self.log.debug("recorder undeclare: %s", exc)
        subscribers.clear()
