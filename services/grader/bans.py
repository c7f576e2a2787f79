"""Bans as the grader learns them: a banned account's submissions are not graded.

A ban reaches every service as the revocation of the account's sessions
(common/revocations.py); the grader then takes the account's queued submissions
out (``on_ban``) and refuses any handed in before the ban that a worker had just
taken. The revocations in force when the grader starts are not news: a ban lifted
since must not fail what the student handed in after.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import zenoh

from common.auth import Verifier
from common.messages import Revocation
from common.revocations import RevocationFeed, is_ban

BANNED = "not graded: the account was banned after handing it in"


class BanWatch:
    """The grader's RevocationFeed (its verifier then refuses revoked sessions too)."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        registry_key: bytes,
        verifier: Verifier,
        on_ban: Callable[[str], None],
    ) -> None:
        self._on_ban = on_ban
        self._banned: dict[str, float] = {}  # user -> when the ban reached us
        self._lock = threading.Lock()
        self._feed: RevocationFeed | None = None
        self._feed = RevocationFeed(session, realm, registry_key, verifier, self._on_revoked)

    def _on_revoked(self, revocation: Revocation) -> None:
        feed = self._feed
        if not is_ban(revocation) or feed is None or not feed.loaded.is_set():
            return
        with self._lock:
            self._banned[revocation.user] = time.time()
        self._on_ban(revocation.user)

    def before_ban(self, user: str, submitted_at: float) -> bool:
        """Whether a submission was handed in before a ban of its account reached us."""
        with self._lock:
            return submitted_at <= self._banned.get(user, -1.0)

    def close(self) -> None:
        if self._feed is not None:
            self._feed.close()
