"""A LabClient's rooms: join, leave, say, kick, a context's requests, the rooms' events.

A part the client holds (``client.rooms``), given what it needs: the Zenoh
session, the realm, the registry's verifier, the client's current session
(it changes at login and logout), its ask and its seal. The client binds the
part's calls as its own, so ``client.join(...)`` reads as it always did.
A client joins a room again by itself when the room forgot it (a restart,
a router blip): the room's liveliness token coming back, or a refusal that
says "join first".
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import zenoh

from common import keys, qos
from common.auth import AuthError, Session, Verifier
from common.client.client_ask import ClientAsk
from common.keys import AliveKind
from common.lab_errors import LabError, NotAllowed
from common.messages import (
    AgentEvent,
    ChatSay,
    JoinReply,
    JoinRoom,
    LeaveRoom,
    Message,
    MessageError,
    OkReply,
    RoomEvent,
    UserRemovalRequest,
)

log = logging.getLogger("wart.client")

M = TypeVar("M", bound=Message)


@dataclass
class RoomHandle:
    """A room this client joined: what the join said, kept up to date by events."""

    ctx: str
    title: str
    owner: str
    members: list[str]
    history: list[Any]
    max_line: int
    subscriber: Any = None
    events: list[RoomEvent] = field(default_factory=list)
    on_agent_event: Callable[[AgentEvent], None] | None = None
    watch: Any = None  # the room's liveliness: when it comes back, this client joins again
    rejoins: int = 0  # times this client joined again by itself (room restart, router blip)


class RoomCalls:
    """A LabClient's rooms; each call raises a LabError in the user's words."""

    def __init__(
        self,
        zsession: zenoh.Session,
        realm: str,
        verifier: Verifier,
        session: Callable[[], Session | None],
        ask: ClientAsk,
        seal: Callable[[str, Message], bytes],
    ) -> None:
        self.z = zsession
        self.realm = realm
        self.verifier = verifier
        self._session = session
        self._ask = ask
        self._seal = seal
        self._rooms: dict[str, RoomHandle] = {}
        self._lock = threading.Lock()

    def join(
        self,
        ctx: str,
        on_event: Callable[[RoomEvent], None] = lambda _e: None,
        history: int = 50,
        *,
        on_agent_event: Callable[[AgentEvent], None] | None = None,
    ) -> RoomHandle:
        """Join a room; events (lines, status changes) go to ``on_event`` from then on.

        An agent context also publishes AgentEvents (queues, request status,
        controller output): they go to ``on_agent_event``, and are ignored
        quietly without one (a chat-only client in an agent context).
        """
        keys.check_ident("room", ctx)
        subscriber = self.z.declare_subscriber(
            keys.ctx_events(self.realm, ctx), lambda s: self._on_event(ctx, s, on_event)
        )
        try:
            reply = self._ask(
                keys.ctx_join(self.realm, ctx),
                JoinRoom(history=history),
                JoinReply,
                f"join {ctx}",
                not_found=f"room {ctx} not found (no context of that name is running)",
            )
        except BaseException:
            subscriber.undeclare()
            raise
        room = RoomHandle(
            ctx=ctx,
            title=reply.title,
            owner=reply.owner,
            members=list(reply.members),
            history=list(reply.history),
            max_line=reply.max_line,
            subscriber=subscriber,
            on_agent_event=on_agent_event,
        )
        # A restarted room, or one that lost us in a router blip, no longer counts us
        # as a member: when its token comes back we join again, without the user.
        room.watch = self.z.liveliness().declare_subscriber(
            keys.alive(self.realm, AliveKind.CONTEXT, ctx),
            lambda s: self._on_room_alive(ctx, s),
        )
        with self._lock:
            self._rooms[ctx] = room
        return room

    def _on_room_alive(self, ctx: str, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            # Not in Zenoh's callback thread: the join is a query of its own.
            threading.Thread(target=self.rejoin, args=(ctx,), daemon=True).start()

    def rejoin(self, ctx: str) -> bool:
        """Join a room this client is in again (the room forgot it); False if that failed."""
        room = self._rooms.get(ctx)
        if room is None or self._session() is None:
            return False
        try:
            reply = self._ask(
                keys.ctx_join(self.realm, ctx), JoinRoom(history=0), JoinReply, f"join {ctx}"
            )
        except LabError as exc:
            log.info("could not join %s again: %s", ctx, exc)
            return False
        room.members = list(reply.members)
        room.rejoins += 1
        log.info("joined %s again (it had restarted or lost us)", ctx)
        return True

    def _member_call(self, ctx: str, call: Callable[[], M]) -> M:
        """``call`` on a room; if the room says we are not a member (it forgot us), join
        again once and retry."""
        try:
            return call()
        except NotAllowed as exc:
            if ctx not in self._rooms or "first" not in str(exc) or not self.rejoin(ctx):
                raise
            return call()

    def _on_event(
        self, ctx: str, sample: zenoh.Sample, on_event: Callable[[RoomEvent], None]
    ) -> None:
        try:
            principal, event = self.verifier.open(
                str(sample.key_expr), sample.payload, (RoomEvent, AgentEvent)
            )
        except (AuthError, MessageError) as exc:
            log.warning("ignored an event of %s: %s", ctx, exc)
            return
        # Only a session allowed to host contexts may speak for a room.
        if not principal.has("host") or event.ctx != ctx:
            log.warning("ignored an event of %s from %s", ctx, principal.user)
            return
        room = self._rooms.get(ctx)
        if isinstance(event, AgentEvent):
            handler = room.on_agent_event if room is not None else None
            if handler is not None:
                handler(event)
            return
        if room is not None:
            room.members = list(event.members)
        on_event(event)

    def room(self, ctx: str) -> RoomHandle | None:
        return self._rooms.get(ctx)

    def joined(self) -> list[str]:
        """The rooms this client is in."""
        return list(self._rooms)

    def forget(self) -> None:
        """Stop hearing every room and forget them (the client logs out or closes)."""
        for room in self._rooms.values():
            if room.subscriber is not None:
                try:
                    room.subscriber.undeclare()
                except Exception as exc:
                    log.debug("undeclare: %s", exc)
        self._rooms.clear()

    def leave(self, ctx: str, reason: str = "") -> None:
        with self._lock:
            room = self._rooms.pop(ctx, None)
        if room is not None and room.watch is not None:
            room.watch.undeclare()
        try:
            self._ask(
                keys.ctx_leave(self.realm, ctx),
                LeaveRoom(reason=reason[:256]),
                OkReply,
                f"leave {ctx}",
                not_found=f"room {ctx} not found",
            )
        finally:
            if room is not None and room.subscriber is not None:
                room.subscriber.undeclare()

    def say(self, ctx: str, text: str, *, wait: bool = True) -> None:
        """Say a line in a room; with ``wait`` the room's refusal (too long, too fast) is raised."""
        if wait:
            self._member_call(
                ctx,
                lambda: self._ask(
                    keys.ctx_request(self.realm, ctx),
                    ChatSay(text=text),
                    OkReply,
                    f"say in {ctx}",
                    not_found=f"room {ctx} not found",
                ),
            )
        else:
            key = keys.ctx_in(self.realm, ctx)
            self.z.put(key, self._seal(key, ChatSay(text=text)), **qos.of(keys.ctx_in))

    def kick(self, ctx: str, user: str, reason: str = "") -> None:
        """Remove ``user`` from a room (needs the kick permission there)."""
        self._ask(
            keys.ctx_request(self.realm, ctx),
            UserRemovalRequest(user=user, reason=reason),
            OkReply,
            f"kick {user} from {ctx}",
            not_found=f"room {ctx} not found",
        )

    def request(
        self,
        ctx: str,
        message: Message,
        expected: type[M],
        what: str,
        *,
        key: str | None = None,
        timeout: float | None = None,
    ) -> M:
        """Send ``message`` to a context's request queryable (or ``key``, another of the
        context's queryables); its reply, or a LabError."""
        return self._member_call(
            ctx,
            lambda: self._ask(
                key or keys.ctx_request(self.realm, ctx),
                message,
                expected,
                what,
                not_found=f"context {ctx} not found (no context of that name is running)",
                timeout=timeout,
            ),
        )
