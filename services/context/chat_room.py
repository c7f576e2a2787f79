"""``wart context chat --name ROOM``: a chat room (the thesis's ChatContext, 7.4.1).

Members join and leave (everyone sees the member list), chat lines are
broadcast with the verified sender's name, status changes (joined, left,
kicked, disconnected) are announced, and a bounded history is kept on disk so
a late joiner sees the recent conversation, also after a restart. A user with
``kick`` in the room (or the room's owner) removes members
(UserRemovalRequest). Users kicked from the server, logged out, or whose
client vanished (presence token gone) are dropped.

Every request is an AuthEnvelope opened with the Verifier and checked against
the ACL of this room (scope ``ctx/<room>``) before it has any effect. The room
logs in as a service account with an Ed25519 identity key and seals its
events with that session, so clients can tell them from forgeries.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import deque
from pathlib import Path

import msgspec
import zenoh

from common import acl, keys, qos
from common.audit import AuditReporter
from common.auth import AuthError, Principal, Verifier
from common.client.service_login import ServiceLogin
from common.files import write_atomic
from common.keys import AliveKind
from common.messages import (
    MAX_LINE_CHARS,
    ChatLine,
    ChatSay,
    ContextInfo,
    ContextInfoRequest,
    JoinReply,
    JoinRoom,
    LeaveRoom,
    MemberStatus,
    Message,
    OkReply,
    Revocation,
    RoomEvent,
    UserRemovalRequest,
)
from common.messages.chat import StatusKind
from common.revocations import RevocationFeed
from common.service import RequestError, Service

log = logging.getLogger("wart.chat")


class History:
    """The last ``size`` lines, in memory and in a JSON-lines file (compacted as it grows)."""

    def __init__(self, path: Path | None, size: int) -> None:
        self.path = path
        self.size = size
        self.lines: deque[ChatLine] = deque(maxlen=size)
        self.next_seq = 1
        self._written = 0
        self._lock = threading.Lock()
        if path is not None and path.exists():
            self._load(path)

    def _load(self, path: Path) -> None:
        decoder = msgspec.json.Decoder(ChatLine)
        bad = 0
        for raw in path.read_bytes().splitlines():
            try:
                line = decoder.decode(raw)
            except msgspec.DecodeError:
                bad += 1  # a torn last line after a crash, or a hand edit
                continue
            self.lines.append(line)
            self.next_seq = max(self.next_seq, line.seq + 1)
            self._written += 1
        if bad:
            log.warning("skipped %d unreadable lines of %s", bad, path)

    def add(self, sender: str, text: str) -> ChatLine:
        with self._lock:
            line = ChatLine(seq=self.next_seq, sender=sender, text=text, at=time.time())
            self.next_seq += 1
            self.lines.append(line)
            if self.path is not None:
                if self._written >= 2 * self.size:
                    self._compact()
                with self.path.open("ab") as out:
                    out.write(msgspec.json.encode(line) + b"\n")
                    out.flush()
                    os.fsync(out.fileno())  # the line is acknowledged once this returns
                self._written += 1
            return line

    def _compact(self) -> None:
        assert self.path is not None
        write_atomic(self.path, b"".join(msgspec.json.encode(line) + b"\n" for line in self.lines))
        self._written = len(self.lines)

    def recent(self, count: int) -> list[ChatLine]:
        with self._lock:
            return list(self.lines)[-count:] if count else []


class RateLimit:
    """A token bucket per user: ``burst`` lines at once, ``per_second`` refilled."""

    def __init__(self, burst: float, per_second: float) -> None:
        self.burst = burst
        self.per_second = per_second
        self._buckets: dict[str, tuple[float, float]] = {}
        self._lock = threading.Lock()

    def take(self, user: str, now: float) -> float:
        """0 if allowed, else the seconds to wait."""
        with self._lock:
            level, at = self._buckets.get(user, (self.burst, now))
            level = min(self.burst, level + (now - at) * self.per_second)
            if level < 1.0:
                self._buckets[user] = (level, now)
                return (1.0 - level) / self.per_second
            self._buckets[user] = (level - 1.0, now)
            return 0.0


def room_allows(
    principal: Principal, permission: str, *, owner: str, scope: str, restricted: bool
) -> bool:
    """The rule of every room: its owner may do anything there; anyone else needs
    ``permission`` in its scope (``kick`` there is what makes a manager)."""
    return principal.user == owner or principal.allowed(permission, scope, restricted=restricted)


class ChatRoom(Service):
    kind = AliveKind.CONTEXT

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        room: str,
        *,
        registry_key: bytes,
        login: ServiceLogin,
        owner: str,
        title: str = "",
        data_dir: Path | None = None,
        history_size: int = 200,
        max_line: int = MAX_LINE_CHARS,
        burst: float = 10.0,
        per_second: float = 2.0,
        restricted: bool = False,
        kick_ban: float = 300.0,
    ) -> None:
        super().__init__(session, realm, room)
        self.room = room
        self.scope = acl.context_scope(room)
        self.registry_key = registry_key
        self.login = login
        self.owner = owner
        self.title = title or room
        self.max_line = max_line
        self.restricted = restricted
        self.kick_ban = kick_ban
        self.verifier = Verifier(registry_key, realm)
        path = None
        if data_dir is not None:
            data_dir.mkdir(parents=True, exist_ok=True)
            path = data_dir / f"{room}.jsonl"
        self.history = History(path, history_size)
        self.rate = RateLimit(burst, per_second)
        self._members: dict[str, set[bytes]] = {}  # user -> session ids in the room
        self._banned: dict[str, float] = {}  # user -> until (kicked from the room)
        self._lock = threading.RLock()
        self._feed: RevocationFeed | None = None
        self._events_key = keys.ctx_events(realm, room)
        self._publisher: zenoh.Publisher | None = None
        # Kicks, emergency stops, settings: reported to the registry's audit trail.
        self.audit = AuditReporter(session, realm, lambda key, m: self.login.session.seal(key, m))

    # -- lifecycle

    def on_start(self) -> None:
        self._publisher = self.track(
            self.session.declare_publisher(self._events_key, **qos.of(keys.ctx_events))
        )
        self._feed = RevocationFeed(
            self.session, self.realm, self.registry_key, self.verifier, self._on_revoked
        )
        self.serve(keys.ctx_join(self.realm, self.room), self.on_join)
        self.serve(keys.ctx_leave(self.realm, self.room), self.on_leave)
        self.serve(keys.ctx_state(self.realm, self.room), self.on_state)
        self.serve(keys.ctx_request(self.realm, self.room), self.on_request)
        self.subscribe(keys.ctx_in(self.realm, self.room), self.on_in)
        self.track(
            self.session.liveliness().declare_subscriber(
                keys.alive_of_kind(self.realm, AliveKind.USER), self._on_presence
            )
        )

    def on_stop(self, timeout: float) -> None:
        if self._feed is not None:
            self._feed.close()

    # -- helpers

    def members(self) -> list[str]:
        with self._lock:
            return sorted(self._members)

    def _publish(self, *, line: ChatLine | None = None, status: MemberStatus | None = None) -> None:
        event = RoomEvent(ctx=self.room, line=line, status=status, members=self.members())
        assert self._publisher is not None
        self._publisher.put(self.login.session.seal(self._events_key, event))

    def _allowed(self, principal: Principal, permission: str) -> bool:
        return room_allows(
            principal, permission, owner=self.owner, scope=self.scope, restricted=self.restricted
        )

    def _require(self, principal: Principal, permission: str, what: str) -> None:
        if not self._allowed(principal, permission):
            raise AuthError(
                "forbidden",
                f"user {principal.user} does not have the '{permission}' permission in room "
                f"{self.room} to {what}",
            )

    def _require_member(self, principal: Principal) -> None:
        with self._lock:
            if principal.session_id not in self._members.get(principal.user, ()):
                raise RequestError("forbidden", f"join room {self.room} first")

    def _drop(self, user: str, status: MemberStatus) -> None:
        with self._lock:
            if self._members.pop(user, None) is None:
                return
        log.info("%s %s room %s", user, status.status, self.room)
        self._publish(status=status)

    # -- requests

    def on_join(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, JoinRoom)
        self._require(principal, "join", "join")
        with self._lock:
            until = self._banned.get(principal.user, 0.0)
            if until > time.time():
                raise RequestError(
                    "forbidden",
                    f"you were removed from room {self.room}; you may come back in "
                    f"{int(until - time.time()) + 1} s",
                )
            sessions = self._members.setdefault(principal.user, set())
            first = not sessions
            sessions.add(principal.session_id)
        if first:
            self._publish(status=MemberStatus(user=principal.user, status="joined"))
        return JoinReply(
            ctx=self.room,
            title=self.title,
            owner=self.owner,
            members=self.members(),
            history=self.history.recent(request.history),
            max_line=self.max_line,
        )

    def on_leave(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, LeaveRoom)
        self.on_session_left(principal, request.reason)
        with self._lock:
            sessions = self._members.get(principal.user)
            if sessions is None or principal.session_id not in sessions:
                return OkReply(detail="not a member")
            sessions.discard(principal.session_id)
            gone = not sessions
            if gone:
                del self._members[principal.user]
        if gone:
            self._publish(status=MemberStatus(user=principal.user, status="left"))
        return OkReply(detail=f"left {self.room}")

    def on_session_left(self, principal: Principal, reason: str = "") -> None:
        """A member's session asked to leave, for ``reason`` (subclasses drop what it held)."""

    def on_state(self, query: zenoh.Query) -> Message:
        self.verifier.open(str(query.key_expr), query.payload, ContextInfoRequest)
        return ContextInfo(
            ctx=self.room, kind="chat", owner=self.owner, title=self.title, members=self.members()
        )

    def on_request(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr), query.payload, (ChatSay, UserRemovalRequest)
        )
        if isinstance(request, ChatSay):
            self._say(principal, request)
            return OkReply()
        with self.audit.action(principal, "kick", f"{self.scope}/{request.user}", request.reason):
            return self._kick(principal, request)

    def on_in(self, sample: zenoh.Sample) -> None:
        principal, request = self.verifier.open(str(sample.key_expr), sample.payload, ChatSay)
        self._say(principal, request)

    def _say(self, principal: Principal, request: ChatSay) -> None:
        self._require_member(principal)
        self._require(principal, "chat", "chat")
        text = request.text.strip()
        if not text:
            raise RequestError("bad_request", "an empty line is not sent")
        if len(text) > self.max_line:
            raise RequestError(
                "bad_request",
                f"line too long: {len(text)} characters, room {self.room} takes {self.max_line}",
            )
        wait = self.rate.take(principal.user, time.monotonic())
        if wait > 0:
            raise RequestError(
                "rate_limited",
                f"you are sending lines too fast: wait {wait:.1f} s",
                retry_after=wait,
            )
        self._publish(line=self.history.add(principal.user, text))

    def _kick(self, principal: Principal, request: UserRemovalRequest) -> Message:
        self._require(principal, "kick", f"remove {request.user}")
        if request.user == self.owner:
            raise RequestError("forbidden", f"{request.user} owns room {self.room}")
        with self._lock:
            if request.user not in self._members:
                raise RequestError("not_found", f"{request.user} is not in room {self.room}")
            self._banned[request.user] = time.time() + self.kick_ban
        reason = request.reason or "no reason given"
        self._drop(
            request.user,
            MemberStatus(user=request.user, status="kicked", reason=reason, by=principal.user),
        )
        return OkReply(detail=f"{request.user} removed from {self.room}")

    # -- the registry's and Zenoh's news

    def _on_revoked(self, rev: Revocation) -> None:
        with self._lock:
            sessions = self._members.get(rev.user)
            if sessions is None or rev.session_id not in sessions:
                return
            sessions.discard(rev.session_id)
            if sessions:
                return
        status: StatusKind = "kicked" if rev.kicked else "left"
        self._drop(rev.user, MemberStatus(user=rev.user, status=status, reason=rev.reason))

    def _on_presence(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        parsed = keys.parse_alive(self.realm, str(sample.key_expr))
        if parsed is None:
            return
        self._drop(
            parsed[1],
            MemberStatus(user=parsed[1], status="disconnected", reason="the client went away"),
        )
