"""What can go wrong for a user of the lab, in their words: every LabClient error.

``str()`` of each is the message to show (wrong password, not allowed, room
not found, registry unreachable, registry key mismatch).
"""

from __future__ import annotations

from common.messages import ErrorReply


class LabError(Exception):
    """Something the user should be told; ``str()`` is the message."""


class RegistryUnreachable(LabError):
    pass


class RegistryKeyMismatch(LabError):
    pass


class WrongCredentials(LabError):
    pass


class NotAllowed(LabError):
    pass


class NotFound(LabError):
    pass


class RateLimited(LabError):
    def __init__(self, message: str, retry_after: float) -> None:
        super().__init__(message)
        self.retry_after = retry_after


class Banned(LabError):
    """The account is banned; the message says why and until when."""

    def __init__(self, message: str, retry_after: float) -> None:
        super().__init__(message)
        self.retry_after = retry_after  # 0: until an admin lifts it


class NotLoggedIn(LabError):
    pass


class RequestFailed(LabError):
    pass


def raise_for(reply: ErrorReply, what: str) -> None:
    """The LabError an ErrorReply stands for, raised, with ``what`` was asked for."""
    text = f"{what}: {reply.message}"
    if reply.code == "forbidden":
        raise NotAllowed(text)
    if reply.code == "not_found":
        raise NotFound(text)
    if reply.code == "rate_limited":
        raise RateLimited(text, reply.retry_after)
    if reply.code == "unauthenticated":
        raise NotLoggedIn(text)
    raise RequestFailed(text)
