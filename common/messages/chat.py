"""Wire types of chat rooms (the thesis's ChatContext, 7.4.1).

Clients send requests as AuthEnvelopes: join/leave/kick as queries (they need
an answer), chat lines as puts on ctx/<ctx>/in. The room publishes
:class:`RoomEvent` messages on ctx/<ctx>/events, sealed with the room's own
service session so clients can tell them from forgeries.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText

MAX_LINE_CHARS = 2000
"""The longest chat line a room accepts (a room may set a lower limit)."""

LineText = Annotated[str, msgspec.Meta(max_length=16 * 1024)]
"""Decoding bound only: the room's own limit is checked with a clear error."""


class JoinRoom(Message, frozen=True):
    history: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 50  # how many recent lines to send


class LeaveRoom(Message, frozen=True):
    """Leave a room (the sender's session says who)."""

    # Why, in the member's words, for what the room ends with the session (its runs):
    # "the page was closed for more than 2 min". Empty: the member left.
    reason: ShortText = ""


class ChatSay(Message, frozen=True):
    """A chat line from a member (put on ctx/<ctx>/in, or a query on ctx/<ctx>/request)."""

    text: LineText


class UserRemovalRequest(Message, frozen=True):
    """Remove a member from the room (thesis 7.4.1); needs ``kick`` there."""

    user: Ident
    reason: ShortText = ""


class ChatLine(Message, frozen=True):
    seq: NonNegInt  # the room's line number: strictly increasing, survives restarts
    sender: Ident  # the verified sender
    text: LineText
    at: float


StatusKind = Literal["joined", "left", "kicked", "disconnected"]


class MemberStatus(Message, frozen=True):
    user: Ident
    status: StatusKind
    reason: ShortText = ""
    by: Ident | None = None  # who kicked


class RoomEvent(Message, frozen=True):
    """One event of a room, published on ctx/<ctx>/events."""

    ctx: Ident
    line: ChatLine | None = None
    status: MemberStatus | None = None
    members: list[Ident] = msgspec.field(default_factory=list)  # the member list after it


class JoinReply(Message, frozen=True):
    ctx: Ident
    title: ShortText
    owner: Ident
    members: list[Ident]
    history: list[ChatLine]
    max_line: NonNegInt


__all__ = [
    "MAX_LINE_CHARS",
    "ChatLine",
    "ChatSay",
    "JoinReply",
    "JoinRoom",
    "LeaveRoom",
    "MemberStatus",
    "RoomEvent",
    "UserRemovalRequest",
]
