"""Wire types of the audit trail: who did what, on what, from where, and how it ended.

The registry appends every privileged action it does or refuses to the audit
table of its database; other services report theirs (an emergency stop, a
kick from a room, a slot-length change) sealed with their own session, and
admins list and filter the whole trail in one place (docs/SECURITY.md).
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, ShortText

Action = Annotated[str, msgspec.Meta(pattern=r"^[a-z][a-z0-9_.-]{0,39}$")]
"""What was done, as a short name: kick, estop, release, grant, ungrant, add_user ..."""
Outcome = Literal["ok", "refused"]
MAX_AUDIT_PAGE = 5000


class AuditReport(Message, frozen=True):
    """A service's privileged action (or its refusal of one), put on registry/report.

    Sealed by the reporting service's session: the registry records that service as
    the reporter, and takes only reports from sessions with the ``service`` role.
    """

    at: float  # when the service did or refused it (its clock)
    actor: Ident  # whose request it was (the user of the envelope the service opened)
    action: Action
    target: ShortText  # on what: "ctx/arena", "alice", "agent/arena/k0"
    outcome: Outcome
    detail: ShortText = ""  # the reason given, or the refusal's words
    source: ShortText = ""  # where the actor's request came from, as the service saw it


class AuditEntry(Message, frozen=True):
    """One line of the audit trail, as stored (never edited once written)."""

    id: int
    at: float
    actor: Ident
    action: Action
    target: ShortText
    outcome: Outcome
    detail: ShortText
    source: ShortText
    reporter: Ident  # "registry", or the service account that reported it


class AuditQuery(Message, frozen=True):
    """List the trail, newest first (admin). Empty filters match everything."""

    actor: Annotated[str, msgspec.Meta(max_length=64)] = ""
    action: Annotated[str, msgspec.Meta(max_length=40)] = ""
    target: Annotated[str, msgspec.Meta(max_length=200)] = ""  # a substring of the target
    outcome: Literal["", "ok", "refused"] = ""
    since: float | None = None
    until: float | None = None
    before_id: int | None = None  # the next page: entries older than this id
    limit: Annotated[int, msgspec.Meta(ge=1, le=MAX_AUDIT_PAGE)] = 200


class AuditList(Message, frozen=True):
    entries: list[AuditEntry]
    more: bool = False  # older entries match too: ask again with before_id


__all__ = [
    "MAX_AUDIT_PAGE",
    "AuditEntry",
    "AuditList",
    "AuditQuery",
    "AuditReport",
]
