"""A service's side of the audit trail: its privileged actions, reported to the registry.

Each report is an AuditReport sealed with the service's own session and put on
``registry/report``; the registry appends it to the one audit table, so one
place answers "who stopped the arena at 10:42?". Fire and forget: a report
never delays nor fails the action it records (a registry that is down misses
it, and the service's own log still has the line).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import zenoh

from common import keys, qos
from common.auth import AuthError, Principal
from common.messages import AuditReport, Message

log = logging.getLogger("wart.audit")

Seal = Callable[[str, Message], bytes]


class AuditReporter:
    """Puts a service's audit lines on ``registry/report``, sealed by ``seal``."""

    def __init__(self, session: zenoh.Session, realm: str, seal: Seal) -> None:
        self.session = session
        self.key = keys.registry_report(realm)
        self.seal = seal

    def report(
        self,
        actor: str,
        action: str,
        target: str,
        outcome: str,
        detail: str = "",
        source: str = "",
    ) -> None:
        try:
            message = AuditReport(
                at=time.time(),
                actor=actor,
                action=action,
                target=target[:256],
                outcome="ok" if outcome == "ok" else "refused",
                detail=detail[:256],
                source=source[:256],
            )
            self.session.put(self.key, self.seal(self.key, message), **qos.of(keys.registry_report))
        except Exception as exc:  # not logged in yet, session closing: the log keeps it
            log.warning("audit line not reported (%s %s %s): %s", actor, action, target, exc)

    @contextmanager
    def action(
        self, principal: Principal, action: str, target: str, detail: str = ""
    ) -> Iterator[None]:
        """Report what the block does for ``principal``: ok, or refused with the error's words."""
        source = f"session {principal.session_id.hex()[:8]}"
        try:
            yield
        except Exception as exc:
            words = getattr(exc, "message", None) or str(exc) or type(exc).__name__
            if isinstance(exc, AuthError) or hasattr(exc, "code"):
                self.report(principal.user, action, target, "refused", _join(words, detail), source)
            raise
        self.report(principal.user, action, target, "ok", detail, source)


def _join(words: str, detail: str) -> str:
    return f"{words} ({detail})" if detail else words
