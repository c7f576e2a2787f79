"""Wire types of real robots' twins, which the registry keeps and serves (``registry/twins``).

A twin (common/twin/twinfile.py) is a real robot's fitted drive and sensors, kept
versioned in the lab's database beside its accounts (services/lab/twins_db.py), by
arena (the real arena's agent context) and robot: two arenas' k1 are two robots. A
twin kept for no arena (``arena`` None: a lab admin's, or one kept before twins were
per arena) is in force for a robot of that name in an arena without its own. It travels as a
message, never as a shared file: a runner on another machine asks the registry for
the twin of the robot a dry run simulates (:class:`TwinQuery`), ``wart twin`` and
the page list, show and save them. Every request is sealed with the asker's
session; who may read and who may save is the registry's to say
(services/registry/twins.py). A twin file travels as its text and is checked
again, field by field, by whoever reads it.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText, Text

MAX_HISTORY = 200  # version lines in one answer (the newest ones)
# A real robot's name, as a twin file names it (common/twin/twinfile.py).
RobotName = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,25}$")]


class TwinVersion(msgspec.Struct, frozen=True, kw_only=True):
    """One kept version of a robot's twin: the twin file as saved, and who saved it when."""

    version: Annotated[int, msgspec.Meta(ge=1)]
    saved_by: Ident
    saved_at: float  # wall-clock seconds
    document: Text  # the twin file (JSON), checked again by whoever reads it


class TwinQuery(Message, frozen=True):
    """The twin in force of ``arena``'s ``robot``; with ``history``, a line for each kept
    version of it."""

    robot: RobotName
    history: bool = False
    arena: Ident | None = None


class TwinReply(Message, frozen=True):
    """``current`` is None when no twin of the robot is kept; ``arena``: whose it is (None:
    one kept for no arena, in force where the arena has none of its own)."""

    robot: RobotName
    current: TwinVersion | None = None
    arena: Ident | None = None
    # Oldest first: "v1: fitted 2026-12-05 by carol from dance; saved ... by carol".
    history: Annotated[list[ShortText], msgspec.Meta(max_length=MAX_HISTORY)] = msgspec.field(
        default_factory=list
    )
    versions: NonNegInt = 0  # how many are kept (history lists at most MAX_HISTORY)


class TwinListQuery(Message, frozen=True):
    """Every robot with a kept twin."""


class TwinListed(msgspec.Struct, frozen=True, kw_only=True):
    robot: RobotName
    versions: NonNegInt
    current: ShortText  # the line of the version in force
    arena: Ident | None = None  # None: kept for no arena


class TwinList(Message, frozen=True):
    robots: list[TwinListed]


class TwinSave(Message, frozen=True):
    """Keep ``document`` (a twin file) as the newest version of ``arena``'s robot's twin,
    in force at once.

    ``arena``: the agent context of the real arena the robot is in, which the saver owns
    (the page sends its own); lab admins may save without one (a twin for no arena).
    """

    document: Text
    arena: Ident | None = None


class TwinSaved(Message, frozen=True):
    robot: RobotName
    version: Annotated[int, msgspec.Meta(ge=1)]
    model: ShortText  # "k1's twin fitted 2026-12-05 by carol"
    arena: Ident | None = None


__all__ = [
    "MAX_HISTORY",
    "TwinList",
    "TwinListQuery",
    "TwinListed",
    "TwinQuery",
    "TwinReply",
    "TwinSave",
    "TwinSaved",
    "TwinVersion",
]
