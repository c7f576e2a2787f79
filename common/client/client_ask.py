"""How a LabClient's parts reach the lab: the client's own ask, handed to each part.

The client seals the query with its session, waits its timeout, and turns no
answer into a LabError in the user's words (a room that is not running, a
registry that does not answer); a part states what it asks and how to say
it failed.
"""

from __future__ import annotations

from typing import Protocol, TypeVar

from common.messages import Message

M = TypeVar("M", bound=Message)


class ClientAsk(Protocol):
    """A sealed query and its reply of type ``expected``, or a LabError."""

    def __call__(
        self,
        key: str,
        message: Message,
        expected: type[M],
        what: str,
        *,
        not_found: str | None = None,
        timeout: float | None = None,
    ) -> M: ...
