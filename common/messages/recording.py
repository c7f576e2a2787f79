"""Wire types of recordings: list one's runs, download one (``ctx/<ctx>/request``, sealed).

An agent context records every slot (common/recording/); the owner of a run
(the user whose request it was) and the context's managers may list and
download it. A download comes in chunks of at most :data:`MAX_CHUNK` bytes
(a message stays far under the 16 MiB limit): ask again from ``offset``.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText

MAX_CHUNK = 1024 * 1024
MAX_LISTED = 1000


class RecordingInfo(msgspec.Struct, frozen=True, kw_only=True):
    name: Ident  # the run's request id: what RecordingGet asks for
    user: Ident
    agent: Ident
    start: float  # wall-clock seconds
    size: NonNegInt  # bytes of the MCAP file
    status: ShortText = ""  # finished / cancelled / ... (from its summary; "" if none)
    reason: ShortText = ""
    distance_mm: float | None = None
    duration_s: float | None = None  # from its summary (the page lists it); None if none


class RecordingListRequest(Message, frozen=True):
    """List recordings: one's own (``user`` None or oneself); another's needs the manage right."""

    user: Ident | None = None
    all_users: bool = False  # every user's (the manage right)


class RecordingList(Message, frozen=True):
    ctx: Ident
    keep: NonNegInt  # recordings kept per user (the host's --keep-recordings)
    recordings: Annotated[list[RecordingInfo], msgspec.Meta(max_length=MAX_LISTED)]


class RecordingGet(Message, frozen=True):
    """Download a chunk of a recording (its owner, or the manage right).

    ``summary`` asks for the run's summary (JSON) instead of the MCAP file.
    """

    name: Ident
    offset: NonNegInt = 0
    summary: bool = False


class RecordingChunk(Message, frozen=True):
    name: Ident
    offset: NonNegInt
    total: NonNegInt  # the file's size
    data: Annotated[bytes, msgspec.Meta(max_length=MAX_CHUNK)]


__all__ = [
    "MAX_CHUNK",
    "RecordingChunk",
    "RecordingGet",
    "RecordingInfo",
    "RecordingList",
    "RecordingListRequest",
]
