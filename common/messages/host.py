"""Wire types of hosts (``wart host``): load reports and arena placement.

``host/<host>/load``: each host publishes a :class:`HostLoad` every few
seconds and answers a query on the same key with its latest one.
``host/<host>/spawn``: ``AuthEnvelope`` of :class:`SpawnArena` (reply
:class:`ArenaReply`), :class:`SpawnRoom` (reply :class:`RoomReply`),
:class:`StopArena` or :class:`StopRoom` (reply ``OkReply``), from a user
with the ``host`` permission.
"""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

from common.messages.base import Ident, Message, NonNegInt, ShortText

Percent = Annotated[float, msgspec.Meta(ge=0.0, le=100.0 * 1024)]  # summed over cores
Megabytes = Annotated[float, msgspec.Meta(ge=0.0, le=1e9)]
Robots = Annotated[int, msgspec.Meta(ge=1, le=1000)]


HostedState = Literal["starting", "running", "restarting", "failed"]


class ArenaInfo(msgspec.Struct, frozen=True, kw_only=True):
    """One arena (engine + agent context) a host runs."""

    world: Ident
    host: Ident
    map: Ident
    robots: NonNegInt
    owner: Ident  # who asked for it ("lab" for the lab file's own worlds)
    state: HostedState
    started_at: float
    pids: list[NonNegInt] = msgspec.field(default_factory=list)
    rss_mb: Megabytes = 0.0  # resident memory of its processes
    cpu_percent: Percent = 0.0  # of one core, summed over its processes


class RoomInfo(msgspec.Struct, frozen=True, kw_only=True):
    """One chat room a host started on request."""

    name: Ident
    host: Ident
    title: ShortText
    owner: Ident  # who asked for it
    state: HostedState
    started_at: float
    kind: Ident = "chat"  # or a plugin's context type (entry points wart.contexts)


class HostLoad(Message, frozen=True):
    """How busy a host is, and what it runs (``host/<host>/load``)."""

    host: Ident
    at: float  # wall clock of the host
    cpus: NonNegInt
    cpu_percent: Percent  # whole machine, 0..100
    load1: float
    mem_total_mb: Megabytes
    mem_available_mb: Megabytes
    services: list[ShortText]  # "registry", "chat lobby", "engine arena1" (with state)
    arenas: list[ArenaInfo]
    max_arenas: NonNegInt
    accepting: bool  # would take a new arena now
    reason: ShortText = ""  # why not, when it would not
    # Chat rooms started on request; a host that hosts none (a lab file's host)
    # says so with max_rooms 0. Defaults keep older hosts' reports readable.
    rooms: list[RoomInfo] = msgspec.field(default_factory=list)
    max_rooms: NonNegInt = 0


class LoadRequest(Message, frozen=True):
    """Ask a host for its latest HostLoad (no authentication: loads are public)."""


class SpawnArena(Message, frozen=True):
    """Start an arena on this host (``host`` permission)."""

    world: Ident
    map: Ident  # a map name from the host's maps directory, never a path
    robots: Robots | None = None  # None: the map's own robots
    seed: NonNegInt = 1


class StopArena(Message, frozen=True):
    """Stop an arena this host runs (``host`` permission)."""

    world: Ident


class ArenaReply(Message, frozen=True):
    arena: ArenaInfo


class SpawnRoom(Message, frozen=True):
    """Start a chat room on this host, owned by the requester (``host`` permission)."""

    name: Ident  # the room's id: one key chunk, unique in the lab
    title: ShortText = ""
    # "chat", or a context type a plugin gives (wart.contexts, docs/ROBOTS.md), started
    # with ``params`` checked against that type's schema (its ``params``).
    kind: Ident = "chat"
    params: Annotated[dict[Ident, ShortText], msgspec.Meta(max_length=16)] = msgspec.field(
        default_factory=dict
    )


class StopRoom(Message, frozen=True):
    """Stop a chat room this host started on request (``host`` permission)."""

    name: Ident


class RoomReply(Message, frozen=True):
    room: RoomInfo


__all__ = [
    "ArenaInfo",
    "ArenaReply",
    "HostLoad",
    "LoadRequest",
    "RoomInfo",
    "RoomReply",
    "SpawnArena",
    "SpawnRoom",
    "StopArena",
    "StopRoom",
]
