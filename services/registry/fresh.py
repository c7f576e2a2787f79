"""Sessions that logged in with a password moments ago.

Two things are granted only to them: sending the mailbox key a login left for
later (once), and setting the account's password without typing the current one.
A resumed session (a saved login, maybe a stolen cookie) is never fresh. Kept in
memory: a registry restart forgets them, and the password is then asked for.
"""

from __future__ import annotations

import threading


class FreshLogins:
    """Password logins of the last ``within_s`` seconds, by session id."""

    def __init__(self, within_s: float) -> None:
        self.within_s = within_s
        self._at: dict[bytes, float] = {}
        self._lock = threading.Lock()

    def add(self, session_id: bytes, now: float) -> None:
        with self._lock:
            for old in [s for s, t in self._at.items() if now - t > self.within_s]:
                del self._at[old]
            self._at[session_id] = now

    def holds(self, session_id: bytes, now: float) -> bool:
        with self._lock:
            at = self._at.get(session_id)
        return at is not None and now - at <= self.within_s

    def take(self, session_id: bytes, now: float) -> bool:
        """Whether the session is fresh; it is not any more after this (good once)."""
        with self._lock:
            at = self._at.pop(session_id, None)
        return at is not None and now - at <= self.within_s

    def forget(self, session_ids: list[bytes]) -> None:
        with self._lock:
            for session_id in session_ids:
                self._at.pop(session_id, None)
