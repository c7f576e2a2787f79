"""The registry's administration: accounts, grants, kicks, bans, and the audit trail.

The registry holds one :class:`AdminDesk`. Every change an admin
asks for, and every refusal of one, is appended to the audit table
(services/registry/audit_db.py) with who asked, from which source, on what,
and how it ended; other services' reports arrive on ``registry/report``
(sealed with their service session) and land in the same table.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Protocol

import nacl.exceptions
import nacl.public
import zenoh

from common import acl, keys, qos
from common.auth import AuthError, Principal, Verifier
from common.messages import (
    ADMIN_REQUESTS,
    AddUser,
    AuditList,
    AuditQuery,
    AuditReport,
    AuthEnvelope,
    BanInfo,
    BanUser,
    ClearThrottle,
    Grant,
    KickFromServer,
    KickNotice,
    LiftBan,
    ListThrottles,
    ListUsers,
    Message,
    MessageError,
    OkReply,
    RemoveUser,
    RenameServer,
    SetPassword,
    ThrottleInfo,
    ThrottleList,
    Ungrant,
    UnlockLogins,
    UserInfo,
    UserList,
    decode,
)
from common.service import RequestError
from services.registry.accounts_db import DbError, RegistryDB
from services.registry.audit_db import Action, TermStore
from services.registry.fresh import FreshLogins
from services.registry.resume import ResumeStore
from services.registry.throttle import LoginThrottle, query_source

log = logging.getLogger("wart.registry")

REGISTRY_USER = "registry"  # the registry's own session (kick notices, context queries)

# What each admin request is called in the audit trail.
ACTIONS: dict[type[Message], str] = {
    ListUsers: "list_users",
    AddUser: "add_user",
    SetPassword: "set_password",
    RemoveUser: "remove_user",
    Grant: "grant",
    Ungrant: "ungrant",
    KickFromServer: "kick",
    RenameServer: "rename_server",
    UnlockLogins: "unlock_logins",
    BanUser: "ban",
    LiftBan: "lift_ban",
    ListThrottles: "list_throttles",
    ClearThrottle: "clear_throttle",
}
READS = (ListUsers, ListThrottles)  # looking is not a change: only its refusals are recorded


class Revoke(Protocol):
    """The registry's revocation of sessions (recorded, published); how many it revoked."""

    def __call__(
        self,
        session_ids: list[bytes],
        reason: str,
        *,
        kicked: bool = ...,
        keep_resume: bool = ...,
    ) -> int: ...


def when(at: float | None) -> str:
    """A ban's end in words: a UTC date and time, or until an admin lifts it."""
    if at is None:
        return "until an admin lifts it"
    return "until " + datetime.fromtimestamp(at, UTC).strftime("%Y-%m-%d %H:%M UTC")


def source_of(query: zenoh.Query | zenoh.Sample) -> str:
    """Where a query (or put) came from, as the network says: the sender's Zenoh session."""
    info = query.source_info
    zid = None if info is None or info.source_id is None else str(info.source_id.zid)
    return query_source(zid)


def _target(request: Message) -> tuple[str, str]:
    """(on what, detail) of an admin request, for its audit line."""
    user = getattr(request, "user", "")
    if isinstance(request, Grant | Ungrant):
        return user, f"{request.grant} {'in ' + request.scope if request.scope else 'everywhere'}"
    if isinstance(request, KickFromServer):
        return user, request.reason
    if isinstance(request, BanUser):
        return user, f"{request.reason} ({when(request.until)})"
    if isinstance(request, LiftBan):
        return user, request.reason
    if isinstance(request, AddUser):
        return user, "roles " + ", ".join(request.roles)
    if isinstance(request, RenameServer):
        return "server", request.name
    if isinstance(request, ClearThrottle):
        return request.source, ""
    return user, ""


class AdminDesk:
    """registry/admin, registry/audit and registry/report, for the Registry that holds it.

    It shares the registry's database, stores, verifier and throttle, and asks the
    registry for what only the registry has: who is online, its own session's seal,
    and revoking sessions (which it also publishes).
    """

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        *,
        db: RegistryDB,
        term: TermStore,
        resumes: ResumeStore,
        verifier: Verifier,
        throttle: LoginThrottle,
        unsealer: nacl.public.SealedBox,
        fresh: FreshLogins,
        online_users: Callable[[], list[str]],
        own_session_seal: Callable[[str, Message], bytes],
        revoke: Revoke,
        announce_ban: Callable[[str, str], None] = lambda _user, _reason: None,
    ) -> None:
        self.session, self.realm = session, realm
        self.db, self.term, self.resumes = db, term, resumes
        self.verifier, self.throttle = verifier, throttle
        self._unsealer = unsealer
        self.fresh = fresh
        self.online_users = online_users
        self.own_session_seal = own_session_seal
        self._revoke = revoke
        self.announce_ban = announce_ban

    # -- the audit trail

    def audit(self, entry: Action) -> None:
        """Append a line; a full disk is logged, never a reason to refuse the action."""
        try:
            self.term.record(entry)
        except Exception as exc:  # sqlite3 errors of every kind, a full disk, a DbError
            log.error("could not append to the audit trail (%s): %s", entry, exc)

    def on_audit(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, AuditQuery)
        try:
            principal.require("admin", "read the audit trail")
        except AuthError as exc:
            self.audit(
                Action(
                    principal.user, "audit_list", "audit", "refused", exc.message, source_of(query)
                )
            )
            raise
        entries, more = self.term.entries(request)
        return AuditList(entries=entries, more=more)

    def on_report(self, sample: zenoh.Sample) -> None:
        """A service's privileged action: only a session with the service role may report.

        Anything else put here is a forged report: it is recorded as one (``forged_report``,
        refused, in words), so `wart audit` shows it; a report seen before (a replay, also
        past a registry restart) is dropped.
        """
        key = str(sample.key_expr)
        try:
            principal, report = self.verifier.open(key, sample.payload, AuditReport)
        except (AuthError, MessageError) as exc:
            words = getattr(exc, "message", None) or str(exc)
            if "replayed message" not in words:
                # A revoked or expired session's report is its user's (its key signed it),
                # though a captured one may be replayed by another: the words say both.
                actor = self.verifier.signer_of(key, sample.payload)
                if actor is not None:
                    words = f"{words} (signed with that session's key: sent late, or replayed)"
                self.audit(
                    Action(
                        actor or "unknown",
                        "forged_report",
                        "audit",
                        "refused",
                        words,
                        source_of(sample),
                    )
                )
            raise
        if "service" not in principal.roles:
            claim = f"{report.actor} {report.action} {report.target} {report.outcome}"
            self.audit(
                Action(
                    principal.user,
                    "forged_report",
                    report.target,
                    "refused",
                    f"{principal.user} is not a service; the report claimed: {claim}",
                    source_of(sample),
                )
            )
            raise AuthError("forbidden", f"{principal.user} is not a service: it reports nothing")
        now = time.time()
        if not self.term.first_report(decode(sample.payload, AuthEnvelope).signature, now):
            log.info("dropped a report of %s seen before (a replay)", principal.user)
            return
        # The service's clock says when; one far from ours (or not a time) is not trusted.
        at = report.at if math.isfinite(report.at) and abs(report.at - now) < 300 else now
        self.audit(
            Action(
                actor=report.actor,
                action=report.action,
                target=report.target,
                outcome=report.outcome,
                detail=report.detail,
                source=report.source,
                reporter=principal.user,
                at=at,
            )
        )

    # -- admin requests

    def _password(self, sealed: bytes) -> str:
        try:
            return self._unsealer.decrypt(sealed).decode("utf-8")
        except (nacl.exceptions.CryptoError, UnicodeDecodeError):
            raise RequestError(
                "bad_request", "the password was not sealed to this registry's key"
            ) from None

    def on_admin(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, ADMIN_REQUESTS)
        action = ACTIONS.get(type(request), type(request).__name__.lower())
        target, detail = _target(request)
        source = f"{source_of(query)} session {principal.session_id.hex()[:8]}"
        try:
            if isinstance(request, SetPassword) and request.user == principal.user:
                self._may_set_own_password(principal, request)
            else:
                principal.require("admin", f"do {type(request).__name__}")
            try:
                reply = self._admin(principal, request)
            except DbError as exc:
                raise RequestError(exc.code, exc.message) from None
        except (AuthError, RequestError) as exc:
            words = f"{exc.message}" + (f" ({detail})" if detail else "")
            self.audit(Action(principal.user, action, target, "refused", words, source))
            raise
        if not isinstance(request, READS):
            self.audit(Action(principal.user, action, target, "ok", detail, source))
        return reply

    def _may_set_own_password(self, principal: Principal, request: SetPassword) -> None:
        """A person sets their own password with the current one, or from a fresh password
        login: a stolen saved login (a resumed session) cannot lock the owner out."""
        if principal.has("admin"):
            return
        now = time.time()
        if request.sealed_current is None:
            if self.fresh.holds(principal.session_id, now):
                return
            raise AuthError(
                "forbidden",
                "type your current password to set a new one (this session did not just "
                "log in with it)",
            )
        # Guessing the current password here is a password guess like a login's.
        source = f"session:{principal.session_id.hex()}"
        self.throttle.check(principal.user, source, now)
        current = self._password(request.sealed_current)
        if not self.db.check_credential(principal.user, "password", current):
            self.throttle.failed(principal.user, source, now)
            raise RequestError("forbidden", "your current password is wrong")
        self.throttle.succeeded(principal.user, source, now, own=False)

    def end_sessions(
        self, user: str, reason: str, *, keep: bytes | None = None, kicked: bool = False
    ) -> int:
        """Every live session and resume token of ``user`` ends (but ``keep``): how many."""
        sessions = [s.session_id for s in self.db.active_sessions(user) if s.session_id != keep]
        self.fresh.forget(sessions)
        count = self._revoke(sessions, reason, kicked=kicked)
        self.resumes.revoke_user(user, reason)
        return count

    def _admin(self, principal: Principal, request: Message) -> Message:
        if isinstance(request, ListUsers):
            return self._list_users()
        if isinstance(request, AddUser):
            if request.user == REGISTRY_USER:
                raise RequestError("conflict", f"the name {REGISTRY_USER} is reserved")
            password = self._password(request.sealed_password) if request.sealed_password else None
            self.db.add_user(
                request.user, request.roles, password=password, public_key=request.public_key
            )
            return OkReply(detail=f"user {request.user} added")
        if isinstance(request, SetPassword):
            self.db.set_password(request.user, self._password(request.sealed_password))
            # A session or saved login outlives no password: all go, but the one that
            # set it (it knows the new password, or is an admin's).
            count = self.end_sessions(
                request.user, "the password was changed", keep=principal.session_id
            )
            return OkReply(detail=f"password of {request.user} changed ({count} sessions ended)")
        if isinstance(request, RemoveUser):
            if request.user == principal.user:
                raise RequestError("conflict", "you cannot remove your own account")
            self.end_sessions(request.user, "account removed", kicked=True)
            self.db.remove_user(request.user)
            return OkReply(detail=f"user {request.user} removed")
        if isinstance(request, Grant):
            self.db.grant(request.user, request.grant, request.scope)
            return OkReply(detail="granted; it takes effect at the user's next login")
        if isinstance(request, Ungrant):
            self.db.ungrant(request.user, request.grant, request.scope)
            return OkReply(detail="revoked; it takes effect at the user's next login")
        if isinstance(request, KickFromServer):
            return self._kick(principal, request.user, request.reason or "no reason given")
        if isinstance(request, BanUser):
            return self._ban(principal, request)
        if isinstance(request, LiftBan):
            if self.term.lift(request.user) is None:
                raise RequestError("not_found", f"{request.user} is not banned")
            log.info("%s lifted the ban on %s", principal.user, request.user)
            return OkReply(detail=f"the ban on {request.user} is lifted: they may log in again")
        if isinstance(request, UnlockLogins):
            if not self.db.user_exists(request.user):
                raise RequestError("not_found", f"no user {request.user}")
            self.throttle.unlock(request.user)
            log.info("%s unlocked the logins of %s", principal.user, request.user)
            return OkReply(detail=f"failed logins of {request.user} forgotten: they may log in now")
        if isinstance(request, ListThrottles):
            buckets = self.throttle.buckets(time.time())
            return ThrottleList(
                throttles=[ThrottleInfo(b.kind, b.key[:256], b.failures, b.wait_s) for b in buckets]
            )
        if isinstance(request, ClearThrottle):
            if not self.throttle.clear_source(request.source):
                raise RequestError("not_found", f"no failed logins from {request.source}")
            log.info("%s cleared the login throttle of %s", principal.user, request.source)
            return OkReply(detail=f"failed logins from {request.source} forgotten")
        if isinstance(request, RenameServer):
            self.db.set_setting("server_name", request.name)
            return OkReply(detail=f"server renamed to {request.name}")
        raise RequestError("bad_request", f"unknown admin request {type(request).__name__}")

    def _list_users(self) -> UserList:
        online = set(self.online_users())
        users = []
        for rec in self.db.users():
            _, _, roles = acl.expand(rec.grants)
            grants: dict[str, list[str]] = {}
            for scope, grant in rec.grants:
                grants.setdefault(scope, []).append(grant)
            users.append(
                UserInfo(
                    name=rec.name,
                    roles=roles,
                    grants=grants,
                    credentials=list(rec.credential_kinds),
                    online=rec.name in online,
                    failed_logins=self.throttle.failures(rec.name),
                    ban=self.term.ban_of(rec.name),
                )
            )
        return UserList(users=users)

    def _ban(self, principal: Principal, request: BanUser) -> Message:
        if request.user == principal.user:
            raise RequestError("conflict", "you cannot ban your own account")
        if request.user == REGISTRY_USER:
            raise RequestError("conflict", f"{REGISTRY_USER} is the registry itself")
        ban = self.term.ban(request.user, request.reason, principal.user, request.until)
        # A ban is a kick that lasts: the live sessions go the same way.
        reason = f"banned {when(ban.until)}: {ban.reason}"
        kicked = self._kick(principal, request.user, reason)
        self.announce_ban(request.user, f"kicked from the server by {principal.user}: {reason}")
        log.info("%s banned %s %s: %s", principal.user, request.user, when(ban.until), ban.reason)
        return OkReply(detail=f"{request.user} banned {when(ban.until)}; {kicked.detail}")

    def _kick(self, principal: Principal, user: str, reason: str) -> OkReply:
        if not self.db.user_exists(user):
            raise RequestError("not_found", f"no user named {user}")
        # Tell the user first, while their client still listens on its inbox.
        key = keys.user_inbox(self.realm, user)
        notice = KickNotice(user=user, reason=reason[:256], by=principal.user)
        self.session.put(key, self.own_session_seal(key, notice), **qos.of(keys.user_inbox))
        why = f"kicked from the server by {principal.user}: {reason}"
        # A page's token too, whichever session it came from.
        count = self.end_sessions(user, why, kicked=True)
        log.info("%s kicked %s from the server (%d sessions)", principal.user, user, count)
        return OkReply(detail=f"{user} kicked ({count} sessions revoked)")


def ban_refusal(ban: BanInfo) -> RequestError:
    """What a banned user is told at login: the reason and the end."""
    retry = 0.0 if ban.until is None else max(0.0, ban.until - time.time())
    return RequestError(
        "forbidden", f"you are banned {when(ban.until)}: {ban.reason} (by {ban.by})", retry
    )
