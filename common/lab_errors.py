"""What can go wrong for a user of the lab, in their words: every LabClient error.

``str()`` of each is the message to show (wrong password, not allowed, room
not found, registry unreachable, registry key mismatch).
"""

from __future__ import annotations

from collections.abc import Mapping

from common.messages import ErrorCode, ErrorReply


class LabError(Exception):
    """Something the user should be told; ``str()`` is the message."""

    # The service's refusal this error stands for, when it is one (see refusal()):
    # a caller that words a refusal its own way reads the service's words here.
    reply: ErrorReply | None = None


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


class NotAnswering(LabError):
    """A service that does not answer: not up yet (an engine compiling), or stopped."""


def refusal(
    reply: ErrorReply, what: str, kinds: Mapping[ErrorCode, type[LabError]] | None = None
) -> LabError:
    """The LabError an ErrorReply stands for, saying ``what`` was asked for.

    ``kinds``: a caller's own error class for some codes (a host's "conflict" is
    a name already taken), built from the same text.
    """
    text = f"{what}: {reply.message}"
    error: LabError
    kind = (kinds or {}).get(reply.code)
    if kind is not None:
        error = kind(text)
    elif reply.code == "forbidden":
        error = NotAllowed(text)
    elif reply.code == "not_found":
        error = NotFound(text)
    elif reply.code == "rate_limited":
        error = RateLimited(text, reply.retry_after)
    elif reply.code == "unauthenticated":
        error = NotLoggedIn(text)
    else:
        error = RequestFailed(text)
    error.reply = reply
    return error
