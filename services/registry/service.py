"""``wart registry``: the Server of the thesis (chapter 5).

Accounts and grants (SQLite, services/registry/accounts_db.py), login with sealed
credentials, signed session tokens, logout and revocations, presence and the
directory of online users and live contexts, private-message mailboxes for
offline users, kick from the server, admin queries, the server's name.

On first start it creates its key (``--key-file``), its database (``--db``)
and an ``admin`` account, and prints the key every service must pin
(``--registry-key``) and the admin's password.
"""

from __future__ import annotations

import logging
import os
import threading
import time

import nacl.exceptions
import nacl.public
import nacl.signing
import zenoh

from common import acl, keys, qos
from common.ask import alive_keys, ask
from common.auth import (
    LOGIN_STALE_S,
    AuthError,
    Principal,
    RegistryIdentity,
    Session,
    Verifier,
    issue_session,
    key_fingerprint,
    new_session_id,
)
from common.keys import AliveKind
from common.lab_errors import LabError
from common.messages import (
    ContextInfo,
    ContextInfoRequest,
    DirectoryReply,
    DirectoryRequest,
    KeyCredential,
    LoginReply,
    LoginRequest,
    LoginVouch,
    LogoutRequest,
    LtiAccountRequest,
    MailboxClaim,
    MailboxContents,
    MailboxDeposit,
    Message,
    MessageError,
    OkReply,
    PasswordCredential,
    PrivateMessage,
    ResumeCheck,
    ResumeCredential,
    Revocation,
    RevocationList,
    SealedLogin,
    SessionToken,
    SignedRevocations,
    UserKeysReply,
    UserKeysRequest,
    decode,
    encode,
)
from common.service import RequestError, Service
from common.worker import Worker
from services.lab.supervisor import AliveWatch
from services.lab.twins_db import TwinStore
from services.registry.accounts_db import DbError, RegistryDB, SessionRecord
from services.registry.admin import REGISTRY_USER, AdminDesk, ban_refusal, source_of
from services.registry.audit_db import Action, TermStore
from services.registry.fresh import FreshLogins
from services.registry.lti_links import LtiLinks
from services.registry.resume import ResumeStore
from services.registry.throttle import LoginThrottle, vouched_source
from services.registry.twins import TwinDesk

log = logging.getLogger("wart.registry")

MAX_TTL = 7 * 24 * 3600.0
CLAIM_WITHIN_S = 600.0  # a deferred mailbox key is sent this soon after the login, or never
REVOCATIONS_SYNC_S = 5.0  # sessions `wart users` revoked in the file are enforced this soon
FRESH_LOGIN_S = 600.0  # a password login may set the password without the current one this long
DEFAULT_SERVER_NAME = "wart lab"


class Registry(Service):
    kind = AliveKind.REGISTRY

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        db: RegistryDB,
        identity: RegistryIdentity,
        *,
        ident: str = "registry",
        throttle: LoginThrottle | None = None,
    ) -> None:
        super().__init__(session, realm, ident)
        self.db = db
        self.term = TermStore(db)
        self.identity = identity
        self.resumes = ResumeStore(db, identity, realm)
        self.lti = LtiLinks(db, self.resumes)
        # Sessions of a password login that left its mailbox key for later: each may
        # send it once (MailboxClaim). Anyone else (a resumed session, a stolen token)
        # must never choose the key the account's offline mail is sealed to.
        self._claims = FreshLogins(CLAIM_WITHIN_S)
        # Password logins of the last minutes: they may set the password without the
        # current one; a resumed session (a stolen cookie) must type it.
        self.fresh = FreshLogins(FRESH_LOGIN_S)
        self.throttle = throttle or LoginThrottle()
        self.verifier = Verifier(identity.verify_key, realm)
        self._unsealer = nacl.public.SealedBox(identity.box_private_key)
        self._own: Session | None = None
        self._own_lock = threading.Lock()
        self._contexts: dict[str, ContextInfo] = {}
        self._contexts_lock = threading.Lock()
        self._refresh = threading.Event()
        self._watch: AliveWatch | None = None
        self._contexts_worker = Worker(self._watch_contexts, "contexts", wake=self._refresh.set)
        self._revocations_worker = Worker(self._sync_revocations, "revoked")
        self._revocation_pub: zenoh.Publisher | None = None
        self.admin = AdminDesk(
            session,
            realm,
            db=db,
            term=self.term,
            resumes=self.resumes,
            verifier=self.verifier,
            throttle=self.throttle,
            unsealer=self._unsealer,
            fresh=self.fresh,
            online_users=self.online_users,
            own_session_seal=self.own_session_seal,
            revoke=self._revoke,
            announce_ban=self.announce_ban,
        )
        # The directory's contexts, replaced whole by _watch_contexts: read without the lock.
        self.twins = TwinDesk(
            TwinStore(db.database), self.verifier, lambda: self._contexts, self.admin.audit
        )

    # -- lifecycle

    def on_start(self) -> None:
        for rec in self.db.revocations():
            self.verifier.revoke(rec.session_id, rec.expires_at)
        self._watch = AliveWatch(self.session, keys.alive_all(self.realm))
        self._revocation_pub = self.track(
            self.session.declare_publisher(
                keys.registry_revocations(self.realm), **qos.of(keys.registry_revocations)
            )
        )
        # argon2id releases the GIL: one worker per core checks passwords in parallel.
        self.serve(
            keys.registry_login(self.realm),
            self.on_login,
            workers=os.cpu_count() or 2,
            stale_after=LOGIN_STALE_S,
        )
        self.serve(keys.registry_logout(self.realm), self.on_logout)
        # Workers: a user-keys answer may ask the router for a presence token (below), which
        # must not happen on Zenoh's own callback thread.
        self.serve(keys.registry_directory(self.realm), self.on_directory, workers=2)
        self.serve(keys.registry_admin(self.realm), self.admin.on_admin)
        self.serve(keys.registry_revocations(self.realm), self.on_revocations)
        self.serve(keys.registry_audit(self.realm), self.admin.on_audit)
        self.serve(keys.registry_lti(self.realm), self.on_lti)
        self.serve(keys.registry_twins(self.realm), self.twins.on_twins)
        self.subscribe(keys.registry_report(self.realm), self.admin.on_report)
        self._contexts_worker.start()
        self._revocations_worker.start()

    def on_stop(self, timeout: float) -> None:
        self._revocations_worker.stopping.set()  # both end together, then each is joined
        self._contexts_worker.stop(timeout)
        self._revocations_worker.stop(timeout)
        if self._watch is not None:
            self._watch.close()
        self.term.flush()  # the refusals counted this minute get their line

    @property
    def server_name(self) -> str:
        return self.db.setting("server_name", DEFAULT_SERVER_NAME)

    def own_session(self) -> Session:
        """The registry's own session: it signs kick notices and its queries to contexts."""
        with self._own_lock:
            if self._own is None or self._own.token.expires_at - time.time() < 3600:
                self._own = issue_session(
                    self.identity, self.realm, REGISTRY_USER, ["admin", "host"], ttl=86400.0
                )
            return self._own

    def own_session_seal(self, key: str, message: Message) -> bytes:
        return self.own_session().seal(key, message)

    # -- login and logout

    def on_login(self, query: zenoh.Query) -> Message:
        sealed = decode(query.payload, SealedLogin)
        try:
            request = decode(self._unsealer.decrypt(sealed.sealed), LoginRequest)
        except nacl.exceptions.CryptoError:
            raise RequestError(
                "bad_request",
                "the login was sealed to another registry key: the registry key you pinned is "
                f"not this registry's (this one's fingerprint is "
                f"{key_fingerprint(self.identity.verify_key)})",
            ) from None
        if request.realm != self.realm:
            raise RequestError(
                "bad_request", f"this registry serves realm {self.realm}, not {request.realm}"
            )
        cred = request.credential
        user = cred.user
        source = self._login_source(query, request)
        now = time.time()
        self.throttle.check(user, source, now, key_login=isinstance(cred, KeyCredential))
        resumed = None
        if isinstance(cred, ResumeCredential):
            try:
                resumed = self.resumes.use(user, cred.token, now)
            except RequestError:
                # A bad token counts as a failed login: guessing tokens is throttled too.
                self.throttle.failed(user, source, now)
                log.info("refused a resume of %s (from %s)", user, source)
                raise
        elif not self._credential_ok(request, now):
            self.throttle.failed(user, source, now)
            log.info("failed login for %s (from %s, says %r)", user, source, request.via)
            what = "key" if isinstance(cred, KeyCredential) else "password"
            raise RequestError("unauthenticated", f"wrong user name or {what}")
        ban = self.term.ban_of(user, now)
        if ban is not None:
            # Told only once the credential is right: a name alone learns nothing.
            refusal = ban_refusal(ban)
            self.admin.audit(Action(user, "login", user, "refused", refusal.message, source))
            raise refusal
        self.throttle.succeeded(user, source, now, own=resumed is None)
        everywhere, scoped, roles = acl.expand(self.db.grants_of(user))
        ends = now + min(request.ttl, MAX_TTL)
        if resumed is not None:
            # No longer than the token allowed: a chain of resumes never outlives the
            # password login it started from, and cannot mint a longer token.
            ends = min(ends, resumed.grant.expires_at)
        token = SessionToken(
            realm=self.realm,
            user=user,
            session_id=new_session_id(),
            session_key=request.session_key,
            box_key=request.box_key,
            permissions=sorted(everywhere),  # type: ignore[arg-type]
            roles=roles,
            issued_at=now,
            expires_at=ends,
            grants=scoped,  # type: ignore[arg-type]
        )
        self.db.record_session(token.session_id, user, request.box_key, now, token.expires_at)
        # No mailbox key: a resume (no password to derive it from), or a client that
        # derives it after its login (MailboxClaim): kept messages stay kept till then.
        pending = []
        if request.mailbox_key is not None:
            pending = self._mailbox(user, request.mailbox_key)
        elif isinstance(cred, PasswordCredential):
            self._claims.add(token.session_id, now)
        if isinstance(cred, PasswordCredential):
            self.fresh.add(token.session_id, now)
        if resumed is not None:
            self.resumes.link(token.session_id, resumed.chain, token.expires_at, now)
        resume = None
        if request.resume and not isinstance(cred, KeyCredential):
            resume = self.resumes.issue(user, token.session_id, token.expires_at, now)
        how = "resumed" if isinstance(cred, ResumeCredential) else "logged in"
        log.info("%s %s (session %s)", user, how, token.session_id.hex()[:8])
        return LoginReply(
            token=self.identity.sign_token(token),
            server_name=self.server_name,
            pending=pending,
            resume=resume,
        )

    def _mailbox(self, user: str, mailbox_key: bytes) -> list[PrivateMessage]:
        """Record ``user``'s mailbox key; the messages kept for them, taken."""
        self.db.set_mailbox_key(user, mailbox_key)
        pending = []
        for raw in self.db.take_mailbox(user):
            try:
                pending.append(decode(raw, PrivateMessage))
            except MessageError as exc:
                log.warning("dropped a damaged stored message for %s: %s", user, exc)
        return pending

    def _login_source(self, query: zenoh.Query, request: LoginRequest) -> str:
        """The throttle's source: the querier's Zenoh session, or what a gateway vouches.

        A vouch that does not hold (forged, replayed, made for another login, from a
        session without ``vouch``) is logged and ignored: the login then counts
        against the querier's session, which never gives more checks.
        """
        plain = source_of(query)
        if request.vouch is None:
            return plain
        try:
            gateway, vouch = self.verifier.open(
                keys.registry_login(self.realm), request.vouch, LoginVouch
            )
            gateway.require("vouch", "vouch for where a login comes from")
            if vouch.session_key != request.session_key:
                raise AuthError("forbidden", "the vouch was made for another login")
        except (AuthError, MessageError) as exc:
            log.warning("ignored a login's vouch (from %s): %s", plain, exc)
            return plain
        return vouched_source(gateway.user, vouch.address)

    def _credential_ok(self, request: LoginRequest, now: float) -> bool:
        cred = request.credential
        if cred.user == REGISTRY_USER or isinstance(cred, ResumeCredential):
            return False
        if isinstance(cred, KeyCredential):
            if abs(now - cred.signed_at) > acl.KEY_LOGIN_MAX_AGE:
                return False
            binding = acl.key_login_binding(
                self.realm, cred.user, request.session_key, request.box_key, cred.signed_at
            )
            try:
                nacl.signing.VerifyKey(cred.public_key).verify(binding, cred.signature)
            except (nacl.exceptions.BadSignatureError, nacl.exceptions.ValueError):
                return False
            return self.db.check_credential(cred.user, "ed25519", cred.public_key)
        return self.db.check_credential(cred.user, "password", cred.password)

    def on_logout(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(str(query.key_expr), query.payload, LogoutRequest)
        if request.everywhere:
            count = self.admin.end_sessions(principal.user, "logged out everywhere")
            return OkReply(detail=f"logged out everywhere ({count} sessions ended)")
        if request.keep_resume:  # a page closing: its saved login stays for the reload
            self._revoke([principal.session_id], "logged out", keep_resume=True)
        else:  # a person's "Log out": every session resumed from the same login goes too
            self._revoke(self.resumes.chain_of(principal.session_id), "logged out")
        return OkReply(detail="logged out")

    # -- LTI launches

    def on_lti(self, query: zenoh.Query) -> Message:
        """A launched LMS user's account (services/registry/lti_links.py): the lti role only."""
        principal, request = self.verifier.open(
            str(query.key_expr), query.payload, LtiAccountRequest
        )
        source = f"{source_of(query)} session {principal.session_id.hex()[:8]}"
        what = f"{request.subject} of {request.issuer} as {request.role} in {request.course}"
        if "lti" not in principal.roles:
            self.admin.audit(Action(principal.user, "lti_account", "lti", "refused", what, source))
            raise AuthError("forbidden", f"{principal.user} is not the lti service")
        existing = self.lti.user_of(request.issuer, request.subject)
        ban = None if existing is None else self.term.ban_of(existing, time.time())
        if ban is not None:
            refusal = ban_refusal(ban)
            self.admin.audit(
                Action(
                    principal.user,
                    "lti_account",
                    existing or "",
                    "refused",
                    refusal.message,
                    source,
                )
            )
            raise refusal
        try:
            reply = self.lti.launch(request)
        except DbError as exc:
            self.admin.audit(
                Action(principal.user, "lti_account", "lti", "refused", exc.message, source)
            )
            raise RequestError(exc.code, exc.message) from None
        how = "made" if reply.created else "matched"
        self.admin.audit(
            Action(principal.user, "lti_account", reply.user, "ok", f"{how}: {what}", source)
        )
        log.info("lti launch: %s %s (%s)", how, reply.user, what)
        return reply

    # -- revocations

    def _revoke(
        self,
        session_ids: list[bytes],
        reason: str,
        *,
        kicked: bool = False,
        keep_resume: bool = False,
    ) -> int:
        if not keep_resume:
            self.resumes.revoke_sessions(session_ids, reason)
        revoked = []
        for session_id in session_ids:
            rec = self.db.revoke(session_id, reason, kicked=kicked)
            if rec is not None:
                self.verifier.revoke(rec.session_id, rec.expires_at)
                revoked.append(_revocation(rec))
        if revoked and self._revocation_pub is not None:
            self._revocation_pub.put(self._signed_revocations(revoked))
        return len(revoked)

    def announce_ban(self, user: str, reason: str) -> None:
        """A ban reaches every service as a revocation even when the account has no live
        session (the grader drops its queued submissions): one naming a session of none."""
        if self._revocation_pub is None:
            return
        gone = Revocation(
            session_id=new_session_id(),
            user=user,
            expires_at=time.time() + 3600,
            reason=reason[:256],
            kicked=True,
        )
        self._revocation_pub.put(self._signed_revocations([gone]))

    def _sync_revocations(self) -> None:
        """Sessions revoked in the database by another hand (`wart users passwd` and
        `remove` on the file, registry running): enforced here and published to every
        service within REVOCATIONS_SYNC_S."""
        while not self._revocations_worker.wait(REVOCATIONS_SYNC_S):
            try:
                found = [
                    r for r in self.db.revocations() if not self.verifier.is_revoked(r.session_id)
                ]
            except Exception as exc:  # a locked or damaged file: next time
                log.warning("could not read the revoked sessions: %s", exc)
                continue
            for rec in found:
                self.verifier.revoke(rec.session_id, rec.expires_at)
            if found and self._revocation_pub is not None:
                self._revocation_pub.put(self._signed_revocations([_revocation(r) for r in found]))

    def _signed_revocations(self, revoked: list[Revocation]) -> bytes:
        body = encode(RevocationList(revoked=revoked, issued_at=time.time()))
        signature = self.identity.signing_key.sign(body).signature
        return encode(SignedRevocations(body=body, signature=signature))

    def on_revocations(self, query: zenoh.Query) -> Message:
        # The list is signed and public: services ask before they hold a session.
        body = encode(
            RevocationList(
                revoked=[_revocation(rec) for rec in self.db.revocations()], issued_at=time.time()
            )
        )
        return SignedRevocations(
            body=body, signature=self.identity.signing_key.sign(body).signature
        )

    # -- presence and directory

    def _alive(self, kind: AliveKind) -> list[str]:
        if self._watch is None:
            return []
        found = []
        for key in self._watch.keys():  # noqa: SIM118 - AliveWatch, not a dict
            parsed = keys.parse_alive(self.realm, key)
            if parsed is not None and parsed[0] == kind:
                found.append(parsed[1])
        return sorted(found)

    def online_users(self) -> list[str]:
        """Users with a presence token and a session in force (a token alone proves nothing)."""
        return [u for u in self._alive(AliveKind.USER) if self.db.active_sessions(u)]

    def _watch_contexts(self) -> None:
        """Keep ContextInfo of every live context, asked on ctx/<ctx>/state.

        Done here, not inside the directory query's callback: waiting for
        replies inside a Zenoh callback would stall the session.
        """
        known: set[str] = set()
        last = 0.0
        while not self._contexts_worker.stopping.is_set():
            self._refresh.wait(0.3)
            self._refresh.clear()
            live = set(self._alive(AliveKind.CONTEXT))
            if live == known and time.monotonic() - last < 2.0:
                continue
            known, last = live, time.monotonic()
            infos = {}
            for ctx in sorted(live):
                info = self._ask_context(ctx)
                infos[ctx] = info or ContextInfo(ctx=ctx, kind="unknown", owner=REGISTRY_USER)
            with self._contexts_lock:
                self._contexts = infos

    def _ask_context(self, ctx: str) -> ContextInfo | None:
        key = keys.ctx_state(self.realm, ctx)
        try:
            return ask(
                self.session,
                key,
                ContextInfoRequest(),
                ContextInfo,
                what=f"context {ctx}",
                timeout=1.0,
                seal=self.own_session().seal,
            )
        except LabError as exc:  # not answering, refusing, or the session closing
            log.debug("context %s did not answer: %s", ctx, exc)
        return None

    def on_directory(self, query: zenoh.Query) -> Message:
        principal, request = self.verifier.open(
            str(query.key_expr),
            query.payload,
            (DirectoryRequest, UserKeysRequest, MailboxDeposit, MailboxClaim, ResumeCheck),
        )
        if isinstance(request, UserKeysRequest):
            return self._user_keys(request.user)
        if isinstance(request, ResumeCheck):
            self.resumes.check(principal.user, principal.session_id, request.token, time.time())
            return OkReply(detail="your saved login is good")
        if isinstance(request, MailboxClaim):
            if not self._claims.take(principal.session_id, time.time()):
                raise AuthError(
                    "forbidden",
                    "only a session that logged in with the password may set the mailbox key, "
                    "once, soon after its login",
                )
            return MailboxContents(pending=self._mailbox(principal.user, request.mailbox_key))
        if isinstance(request, MailboxDeposit):
            return self._deposit(principal, request.message)
        self._refresh.set()
        with self._contexts_lock:
            contexts = [self._contexts[c] for c in sorted(self._contexts)]
        live = set(self._alive(AliveKind.CONTEXT))
        return DirectoryReply(
            server_name=self.server_name,
            users=self.online_users(),
            contexts=[c for c in contexts if c.ctx in live],
        )

    def _user_keys(self, user: str) -> UserKeysReply:
        if not self.db.user_exists(user):
            raise RequestError("not_found", f"no user named {user}")
        sessions = self.db.active_sessions(user)
        online = bool(sessions) and (user in self._alive(AliveKind.USER) or self._present_now(user))
        return UserKeysReply(
            user=user,
            online=online,
            session_box_keys=[s.box_key for s in sessions] if online else [],
            mailbox_key=self.db.mailbox_key(user),
        )

    def _present_now(self, user: str) -> bool:
        """Whether ``user``'s presence token is alive, asked of the router: a login's token
        reaches this registry's watch a little after the login itself on a loaded machine,
        and a message sent then must be delivered live, not kept for the next login."""
        key = keys.alive(self.realm, AliveKind.USER, user)
        try:
            return bool(alive_keys(self.session, key, what=f"{user}'s presence", timeout=1.0))
        except LabError:
            return False

    def _deposit(self, principal: Principal, message: PrivateMessage) -> Message:
        if message.sender != principal.user:
            raise AuthError("forbidden", "a private message must be sent under your own name")
        principal.require("chat", "send private messages")
        if message.to_key != self.db.mailbox_key(message.recipient):
            raise RequestError("conflict", f"{message.recipient}'s mailbox key has changed")
        try:
            self.db.deposit(message.recipient, encode(message))
        except DbError as exc:
            raise RequestError(exc.code, exc.message) from None
        return OkReply(detail=f"kept for {message.recipient} until they log in")


def _revocation(rec: SessionRecord) -> Revocation:
    return Revocation(
        session_id=rec.session_id,
        user=rec.user,
        expires_at=rec.expires_at,
        reason=rec.reason[:256],
        kicked=rec.kicked,
    )


# --- the process ---------------------------------------------------------------------
