"""Host new contexts on a lab: a chat room or a simulated arena, on the host chosen by load.

For any program with a logged-in :class:`~common.client.lab_client.LabClient` (``wart
arena``, ``wart room``, the viewer)::

    room = host_room(client, "reading-group", "Reading group")
    arena = host_arena(client, "arena7", "foraging", robots=5)
    stop_hosted(client, "arena7")

Every host of a lab (each ``wart host`` of a lab file; ``local`` in ``wart
up``) answers ``host/<h>/load`` with its load and what it runs, and serves
``host/<h>/spawn`` for users with the ``host`` permission. The new context is
owned by the requesting user, and appears in the registry's directory once
it is up (within ~2 s). Errors are :class:`~common.lab_errors.LabError`s whose
text says what to do: :class:`NoHost`, :class:`~common.lab_errors.NotAllowed`,
:class:`NameTaken`, :class:`~common.lab_errors.NotFound` (unknown map or context).
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from typing import Literal

import zenoh

from common import keys
from common.ask import NoReply, ask, ask_all
from common.client.lab_client import LabClient
from common.lab_errors import LabError, NotFound, RequestFailed
from common.messages import Message, OkReply
from common.messages.host import (
    ArenaInfo,
    ArenaReply,
    HostLoad,
    LoadRequest,
    RoomInfo,
    RoomReply,
    SpawnArena,
    SpawnRoom,
    StopArena,
    StopRoom,
)

Kind = Literal["arena", "room"]


class HostError(LabError):
    """No host can carry out the request (none answers, all are full), in words."""


class NoHost(HostError):
    """No host of this lab answered: the lab has no hosting service running."""


class NameTaken(RequestFailed):
    """A world or context of that name already runs somewhere in the lab."""


def host_loads(session: zenoh.Session, realm: str, timeout: float = 3.0) -> list[HostLoad]:
    """Every live host's current load (each host answers on its own load key)."""
    answers = ask_all(
        session, keys.host_load_all(realm), LoadRequest(), HostLoad, what="loads", timeout=timeout
    )
    loads = {load.host: load for load in answers}
    return sorted(loads.values(), key=lambda h: h.host)


NO_HOST = (
    "no host serves this lab: neither `wart up` (version with hosting) nor `wart host` "
    "answered on host/*/load"
)


def choose_host(loads: Sequence[HostLoad], wanted: str | None = None) -> HostLoad:
    """The host an arena goes to: ``wanted`` if given, else the least busy that accepts."""
    if wanted is not None:
        for load in loads:
            if load.host == wanted:
                if not load.accepting:
                    raise HostError(f"host {wanted} takes no arena now: {load.reason}")
                return load
        seen = ", ".join(h.host for h in loads) or "none"
        raise HostError(f"host {wanted} did not answer (hosts that did: {seen}); is it running?")
    ready = [h for h in loads if h.accepting]
    if not ready:
        if not loads:
            raise NoHost(NO_HOST)
        why = "; ".join(f"{h.host}: {h.reason}" for h in loads)
        raise HostError(f"no host takes an arena now ({why})")
    return min(ready, key=lambda h: (len(h.arenas) / max(1, h.max_arenas), h.cpu_percent, h.host))


def choose_room_host(loads: Sequence[HostLoad], wanted: str | None = None) -> HostLoad:
    """The host a chat room goes to: ``wanted``, else the one with the most room to spare."""
    if not loads:
        raise NoHost(NO_HOST)
    candidates = [h for h in loads if wanted is None or h.host == wanted]
    if not candidates:
        seen = ", ".join(h.host for h in loads)
        raise HostError(f"host {wanted} did not answer (hosts that did: {seen}); is it running?")
    ready = [h for h in candidates if h.max_rooms > len(h.rooms)]
    if not ready:
        if all(h.max_rooms == 0 for h in candidates):
            raise HostError(
                "no host of this lab starts chat rooms on request "
                f"({', '.join(h.host for h in candidates)}: none configured)"
            )
        raise HostError("every host already runs as many chat rooms as it allows")
    return min(ready, key=lambda h: (len(h.rooms) / h.max_rooms, h.cpu_percent, h.host))


def _ask(client: LabClient, host: str, message: Message, timeout: float) -> Message:
    if client.session is None:
        raise HostError("log in first")
    try:
        return ask(
            client.z,
            keys.host_spawn(client.realm, host),
            message,
            (ArenaReply, RoomReply, OkReply),
            what=f"host {host}",
            timeout=timeout,
            seal=client.session.seal,
            kinds={"conflict": NameTaken, "unavailable": HostError},
        )
    except NoReply:
        raise HostError(
            f"host {host} did not answer: it went away or the network dropped it"
        ) from None


def host_arena(
    client: LabClient,
    world: str | None,
    map_name: str,
    robots: int | None = None,
    *,
    host: str | None = None,
    seed: int = 1,
    timeout: float = 90.0,
) -> ArenaInfo:
    """Start a simulated arena (engine + agent context named ``world``) from a map.

    ``world`` None: ``MAP-xxxx``. ``robots`` None: the map's own robots, else
    that many Khepera on a grid. Returns once the engine and its context are up.
    """
    name = world or f"{map_name}-{uuid.uuid4().hex[:4]}"
    keys.check_ident("world", name)
    keys.check_ident("map", map_name)
    if robots is not None and not 1 <= robots <= 1000:
        raise HostError("the robot count must be between 1 and 1000")
    target = choose_host(host_loads(client.z, client.realm), host)
    reply = _ask(
        client,
        target.host,
        SpawnArena(world=name, map=map_name, robots=robots, seed=seed),
        timeout,
    )
    assert isinstance(reply, ArenaReply)
    return reply.arena


def host_room(
    client: LabClient,
    name: str,
    title: str = "",
    *,
    host: str | None = None,
    timeout: float = 60.0,
    kind: str = "chat",
    params: dict[str, str] | None = None,
) -> RoomInfo:
    """Start a chat room ``name`` owned by the caller; returns once it serves.

    ``kind``: a plugin's context type instead (``wart robots list``), started with
    ``params`` (text values, checked by the host against the type's schema).
    """
    keys.check_ident("room", name)
    target = choose_room_host(host_loads(client.z, client.realm), host)
    request = SpawnRoom(name=name, title=title, kind=kind, params=dict(params or {}))
    reply = _ask(client, target.host, request, timeout)
    assert isinstance(reply, RoomReply)
    return reply.room


def stop_hosted(
    client: LabClient, name: str, kind: Kind | None = None, *, timeout: float = 30.0
) -> str:
    """Stop an arena (by world) or a chat room started on request; returns the host's words."""
    loads = host_loads(client.z, client.realm)
    if not loads:
        raise NoHost(NO_HOST)
    for load in loads:
        if kind != "room" and any(a.world == name for a in load.arenas):
            reply = _ask(client, load.host, StopArena(world=name), timeout)
            assert isinstance(reply, OkReply)
            return reply.detail
        if kind != "arena" and any(r.name == name for r in load.rooms):
            reply = _ask(client, load.host, StopRoom(name=name), timeout)
            assert isinstance(reply, OkReply)
            return reply.detail
    what = {"arena": "an arena", "room": "a chat room", None: "an arena or a chat room"}[kind]
    raise NotFound(f"no host runs {what} named {name} started on request")


__all__ = [
    "HostError",
    "NameTaken",
    "NoHost",
    "choose_host",
    "choose_room_host",
    "host_arena",
    "host_loads",
    "host_room",
    "stop_hosted",
]
