"""The one client of the lab: used by ``wart chat``, the web viewer, services and tests.

    with LabClient(zsession, realm, registry_key) as client:
        client.login("alice", "secret")
        room = client.join("lobby", on_event=print)
        client.say("lobby", "hello")

Every error a user can meet is a :class:`LabError` subclass whose message
says what happened in their words (wrong password, not allowed, room not
found, registry unreachable, registry key mismatch). Callbacks run on Zenoh
threads: keep them short (queue the work).

Services log in with an Ed25519 identity key (``login_with_key``) and keep
their session renewed (common/client/service_login.py). The errors are in
common/lab_errors.py, private messages' crypto in common/client/private_mail.py. The
client holds two parts and binds their calls as its own: its rooms (``client.rooms``,
common/client/rooms.py) and the admin calls (``client.admin``, registry_admin.py).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import nacl.exceptions
import nacl.public
import nacl.pwhash
import nacl.signing
import nacl.utils
import zenoh

from common import acl, keys, qos
from common.ask import NoReply, QueryFailed, ask
from common.auth import (
    LOGIN_FIND_PAUSE_S,
    LOGIN_FIND_S,
    LOGIN_WAIT_S,
    AuthError,
    Session,
    SessionKeys,
    Verifier,
    key_fingerprint,
    parse_public_key,
    registry_box_key,
    resume_user,
)
from common.client.directory_calls import DirectoryCalls
from common.client.private_mail import (
    PrivateText,
    mailbox_key_from_password,
    open_private,
    seal_private,
)
from common.client.registry_admin import RegistryAdminCalls
from common.client.rooms import RoomCalls
from common.client.twins import TwinCalls
from common.keys import AliveKind
from common.lab_errors import (
    Banned,
    LabError,
    NotFound,
    NotLoggedIn,
    RateLimited,
    RegistryKeyMismatch,
    RegistryUnreachable,
    RequestFailed,
    WrongCredentials,
)
from common.messages import (
    ErrorReply,
    KeyCredential,
    KickNotice,
    LoginReply,
    LoginRequest,
    LogoutRequest,
    MailboxClaim,
    MailboxContents,
    MailboxDeposit,
    Message,
    MessageError,
    OkReply,
    PasswordCredential,
    PrivateMessage,
    ResumeCredential,
    SealedLogin,
    SessionToken,
    UserKeysReply,
    UserKeysRequest,
    decode,
    encode,
)
from common.revocations import RevocationFeed

log = logging.getLogger("wart.client")

# Inbox messages kept while a login is in flight (a person gets a handful, not a flood).
_EARLY_INBOX_MAX = 64

M = TypeVar("M", bound=Message)


class LabClient:
    """A user's (or service's) connection to the lab over one Zenoh session."""

    def __init__(
        self,
        zsession: zenoh.Session,
        realm: str,
        registry_key: bytes | str,
        *,
        timeout: float = 5.0,
        presence: bool = True,
        via: str = "",
        voucher: Callable[[bytes], bytes] | None = None,
    ) -> None:
        if isinstance(registry_key, str):
            registry_key = parse_public_key(registry_key)
        self.z = zsession
        self.realm = realm
        self.registry_key = registry_key
        self.timeout = timeout
        self.presence = presence  # services are not people: they announce themselves otherwise
        self.verifier = Verifier(registry_key, realm)
        self.session: Session | None = None
        self.server_name = ""
        self._mailbox: nacl.public.PrivateKey | None = None
        # The registry's resume token of the last login that asked for one (a browser
        # keeps it to come back without a password; see services/registry/resume.py).
        self.resume_token: bytes | None = None
        self.keep_resume = False  # close() logs out leaving the resume token good
        self._token: Any = None
        self._inbox: Any = None
        self._inbox_user = ""  # whose inbox and presence token are declared
        self._early: list[zenoh.Sample] = []  # inbox samples from before the login reply
        self._inbox_lock = threading.Lock()
        self.on_private: Callable[[PrivateText], None] = lambda _m: None
        self.on_kicked: Callable[[KickNotice], None] = lambda _k: None
        self.pending: list[PrivateText] = []  # kept messages received at login
        # Where this client's person says they are: logged by the registry, never a
        # throttle source of its own (docs/SECURITY.md "Failed logins").
        self.via = via[:200]
        # A gateway's vouch for its person's address, given the new session's key
        # (common/client/service_login.py vouch_for): that address is the source.
        self.voucher = voucher
        self._querier: Any = None
        self._source_sn = 0
        self._revocations: RevocationFeed | None = None
        # Its parts, and their calls bound once as its own: callers see one client.
        self.rooms = rooms = RoomCalls(
            zsession, realm, self.verifier, lambda: self.session, self._ask, self._seal
        )
        self.join = rooms.join
        self.rejoin = rooms.rejoin
        self.room = rooms.room
        self.leave = rooms.leave
        self.say = rooms.say
        self.kick = rooms.kick
        self.request = rooms.request
        self.lobby = lobby = DirectoryCalls(realm, self._ask, lambda: self.resume_token)
        self.directory = lobby.directory
        self.check_resume = lobby.check_resume
        self.admin = admin = RegistryAdminCalls(realm, registry_key, self._ask)
        self.list_users = admin.list_users
        self.add_user = admin.add_user
        self.set_password = admin.set_password
        self.remove_user = admin.remove_user
        self.grant = admin.grant
        self.ungrant = admin.ungrant
        self.kick_from_server = admin.kick_from_server
        self.rename_server = admin.rename_server
        self.unlock_logins = admin.unlock_logins
        self.throttles = admin.throttles
        self.clear_throttle = admin.clear_throttle
        self.ban = admin.ban
        self.lift_ban = admin.lift_ban
        self.audit_trail = admin.audit_trail
        self.twins = TwinCalls(realm, self._ask)

    # -- context manager

    def __enter__(self) -> LabClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self, reason: str = "", *, logout: bool = True) -> None:
        """Leave rooms, log out (best effort) and undeclare everything.

        ``reason`` tells each room why, in words its members see with what ends (a run).
        ``logout=False`` leaves no room and keeps the session, as a crash would: only
        the presence token and the subscriptions go, so the rooms see the client go
        away and what runs in simulation goes on (a restarting viewer's hand-over).
        """
        if self.session is not None and logout:
            for ctx in self.rooms.joined():
                try:
                    self.leave(ctx, reason)
                except LabError as exc:
                    log.debug("leaving %s: %s", ctx, exc)
            try:
                self.logout()
            except LabError as exc:
                log.debug("logout: %s", exc)
        if self._revocations is not None:
            self._revocations.close()
            self._revocations = None
        if self._querier is not None:
            try:
                self._querier.undeclare()
            except Exception as exc:  # the session may already be closed
                log.debug("querier: %s", exc)
            self._querier = None
        self._undeclare()

    def _undeclare(self) -> None:
        for handle in (self._token, self._inbox):
            if handle is not None:
                try:
                    handle.undeclare()
                except Exception as exc:
                    log.debug("undeclare: %s", exc)
        self._token = self._inbox = None
        self._inbox_user = ""
        with self._inbox_lock:
            self._early.clear()
        self.rooms.forget()

    # -- queries

    def _source_info(self, key: str) -> zenoh.SourceInfo:
        """This session as the source of a query (the registry throttles failed logins by it).

        zenoh-python builds an entity id only for declared entities, so a querier
        is declared once for it.
        """
        if self._querier is None:  # on the login key, whatever asks: the rights it needs
            self._querier = self.z.declare_querier(keys.registry_login(self.realm))
        self._source_sn += 1
        return zenoh.SourceInfo(self._querier.id, self._source_sn)

    def _ask(
        self,
        key: str,
        message: Message,
        expected: type[M],
        what: str,
        *,
        signed: bool = True,
        not_found: str | None = None,
        timeout: float | None = None,
    ) -> M:
        # The registry records where admin requests come from (the audit trail).
        to_registry = key.startswith(keys.registry_all(self.realm)[:-2])
        try:
            source = self._source_info(key) if to_registry else None
        except zenoh.ZError as exc:  # the session closed under a caller's thread
            raise QueryFailed(what, str(exc)) from None
        try:
            return ask(
                self.z,
                key,
                message,
                expected,
                what=what,
                timeout=timeout or self.timeout,
                seal=self._seal if signed else None,
                source_info=source,
            )
        except NoReply:
            if not_found is not None:
                raise NotFound(not_found) from None
            raise RegistryUnreachable(f"{what}: no answer (is the registry running?)") from None

    def _seal(self, key: str, message: Message) -> bytes:
        if self.session is None:
            raise NotLoggedIn("log in first")
        return self.session.seal(key, message)

    # -- login

    @property
    def user(self) -> str:
        if self.session is None:
            raise NotLoggedIn("not logged in")
        return self.session.user

    def login(
        self,
        user: str,
        password: str,
        *,
        ttl: float = 12 * 3600.0,
        wait: float | None = None,
        resume: bool = False,
        defer_mailbox: bool = False,
    ) -> SessionToken:
        """Log in with a password; raises WrongCredentials, RateLimited, RegistryUnreachable...

        ``wait``: how long to wait for the registry's answer (default: LOGIN_WAIT_S, or
        this client's timeout if longer); a gateway that must answer its user sooner
        passes less. ``resume``: ask for a resume token too (``resume_token``).
        ``defer_mailbox``: log in without deriving the mailbox key (argon2id, as costly as
        the registry's check); the caller derives it after, with :meth:`claim_mailbox`
        (a gateway logging a class in at once on the lab's own cores).
        """
        keys.check_ident("user", user)
        if wait is not None and not wait > 0:
            raise ValueError(f"a login must wait a positive time, not {wait}")
        mailbox = None if defer_mailbox else mailbox_key_from_password(self.realm, user, password)
        cred = PasswordCredential(user=user, password=password)
        return self._login(cred, mailbox, SessionKeys(), ttl, wait, resume=resume)

    def claim_mailbox(self, password: str) -> list[PrivateText]:
        """After a ``defer_mailbox`` login: derive the mailbox key and tell the registry;
        the messages kept while offline, each also given to ``on_private``."""
        if self.session is None:
            raise NotLoggedIn("log in first")
        mailbox = mailbox_key_from_password(self.realm, self.session.user, password)
        reply = self._ask(
            keys.registry_directory(self.realm),
            MailboxClaim(mailbox_key=bytes(mailbox.public_key)),
            MailboxContents,
            "mailbox",
        )
        self._mailbox = mailbox
        kept = [t for t in (self._open_private(m, kept=True) for m in reply.pending) if t]
        for text in kept:
            self.on_private(text)
        return kept

    def resume(
        self, token: bytes, *, ttl: float = 12 * 3600.0, wait: float | None = None
    ) -> SessionToken:
        """Log in again with a resume token from an earlier login (no password check).

        The token is used up; the new one is ``resume_token``. A token that is no good
        (forged, expired, revoked, used) raises WrongCredentials with the registry's
        words ("your saved login expired 3 min ago: log in with your password").
        Messages kept while offline stay kept until the next password login.
        """
        user = resume_user(token)
        if wait is not None and not wait > 0:
            raise ValueError(f"a login must wait a positive time, not {wait}")
        return self._login(
            ResumeCredential(user=user, token=token), None, SessionKeys(), ttl, wait, resume=True
        )

    def login_with_key(
        self, user: str, identity: nacl.signing.SigningKey, *, ttl: float = 24 * 3600.0
    ) -> SessionToken:
        """Log in with an Ed25519 identity key registered for ``user`` (services, scripts)."""
        session_keys = SessionKeys()
        signed_at = time.time()
        binding = acl.key_login_binding(
            self.realm,
            user,
            session_keys.session_public_key,
            session_keys.box_public_key,
            signed_at,
        )
        cred = KeyCredential(
            user=user,
            public_key=bytes(identity.verify_key),
            signed_at=signed_at,
            signature=identity.sign(binding).signature,
        )
        return self._login(cred, identity.to_curve25519_private_key(), session_keys, ttl)

    def _login(
        self,
        cred: PasswordCredential | KeyCredential | ResumeCredential,
        mailbox: nacl.public.PrivateKey | None,
        session_keys: SessionKeys,
        ttl: float,
        wait: float | None = None,
        *,
        resume: bool = False,
    ) -> SessionToken:
        request = LoginRequest(
            realm=self.realm,
            credential=cred,
            session_key=session_keys.session_public_key,
            box_key=session_keys.box_public_key,
            mailbox_key=None if mailbox is None else bytes(mailbox.public_key),
            ttl=ttl,
            via=self.via,
            vouch=self.voucher(session_keys.session_public_key) if self.voucher else None,
            resume=resume,
        )
        sealed = nacl.public.SealedBox(registry_box_key(self.registry_key)).encrypt(encode(request))
        key = keys.registry_login(self.realm)
        # On a first login, be reachable before asking: the inbox, then the presence token,
        # travel ahead of the login query on this link, so by the time the registry has our
        # session it has seen the token, and a message sent to us from then on is delivered
        # live to a subscription the router already has. Declared after the reply instead, a
        # message sent in between was kept in the mailbox until our *next* login.
        early = self.session is None
        if early:
            self._declare_inbox(cred.user)
        try:
            return self._login_reply(key, sealed, session_keys, mailbox, wait)
        except BaseException:
            if early:
                self._undeclare()
            raise

    def _find_registry(self, key: str, payload: bytes, wait: float) -> tuple[list[Any], bool]:
        """The login query's answers, asked again for LOGIN_FIND_S while none is routed to,
        and whether a registry took the query (False: none was routed to).

        A query with no queryable to reach ends at once, empty; one the registry
        took but has not answered (frozen, swamped) ends only at ``wait``, and
        is not asked again (its password check may still be queued there).
        """
        first = time.monotonic()
        deadline = first + wait  # the asker waits no longer in all
        give_up = first + min(LOGIN_FIND_S, wait / 2)
        while True:
            started = time.monotonic()
            # Every answer, raw: _login_reply reads each to find the registry it trusts.
            replies = self.z.get(
                key, payload=payload, timeout=deadline - started, source_info=self._source_info(key)
            )
            answers = [r.ok.payload for r in replies if r.ok is not None]
            ended = time.monotonic()
            # Ended long before its time: routed to no registry, not unanswered by one.
            routed_nowhere = ended - started < (deadline - started) / 2
            if answers or not routed_nowhere or ended + LOGIN_FIND_PAUSE_S >= give_up:
                return answers, bool(answers) or not routed_nowhere
            time.sleep(LOGIN_FIND_PAUSE_S)

    def _login_reply(
        self,
        key: str,
        sealed: bytes,
        session_keys: SessionKeys,
        mailbox: nacl.public.PrivateKey | None,
        wait: float | None,
    ) -> SessionToken:
        waited = wait if wait is not None else max(self.timeout, LOGIN_WAIT_S)
        answers, taken = self._find_registry(key, encode(SealedLogin(sealed=sealed)), waited)
        if not answers and taken:
            raise RegistryUnreachable(
                f"the registry on realm {self.realm} took the login but did not answer in "
                f"{waited:.0f} s: it is swamped or stuck; try again in a minute"
            )
        if not answers:
            raise RegistryUnreachable(
                f"no registry answered on realm {self.realm}: is it running, and is the router "
                "reachable?"
            )
        errors: list[ErrorReply] = []
        foreign = False
        for raw in answers:
            try:
                reply = decode(raw, (LoginReply, ErrorReply))
            except MessageError:
                continue
            if isinstance(reply, ErrorReply):
                errors.append(reply)
                continue
            try:
                token = self.verifier.verify_token(reply.token)
            except AuthError:
                foreign = True
                continue
            if token.session_key != session_keys.session_public_key:
                foreign = True
                continue
            return self._logged_in(Session(session_keys, reply.token, token), reply, mailbox)
        pinned = key_fingerprint(self.registry_key)
        for err in errors:
            if err.code == "unauthenticated":
                raise WrongCredentials(err.message)
            if err.code == "rate_limited":
                raise RateLimited(err.message, err.retry_after)
            if err.code == "forbidden":
                raise Banned(err.message, err.retry_after)
        if foreign or any("sealed to another registry key" in e.message for e in errors):
            raise RegistryKeyMismatch(
                f"the registry that answered is not the one you trust (pinned key {pinned}); "
                "check --registry-key"
            )
        raise RequestFailed("login: " + "; ".join(e.message for e in errors))

    def _logged_in(
        self, session: Session, reply: LoginReply, mailbox: nacl.public.PrivateKey | None
    ) -> SessionToken:
        if self._inbox is None or self._inbox_user != session.user:  # a re-login
            self._undeclare()
            self._declare_inbox(session.user)
        if self._revocations is None:
            # The registry's revocations, so a private message sealed by a kicked or
            # logged-out session is dropped here like anywhere else.
            self._revocations = RevocationFeed(self.z, self.realm, self.registry_key, self.verifier)
        with self._inbox_lock:
            self.session = session
            self._mailbox = mailbox
            early, self._early = self._early, []
        self.server_name = reply.server_name
        self.resume_token = reply.resume
        for sample in early:
            self._deliver(sample)
        self.pending = [t for t in (self._open_private(m, kept=True) for m in reply.pending) if t]
        return session.token

    def _declare_inbox(self, user: str) -> None:
        self._inbox = self.z.declare_subscriber(keys.user_inbox(self.realm, user), self._on_inbox)
        if self.presence:
            self._token = self.z.liveliness().declare_token(
                keys.alive(self.realm, AliveKind.USER, user)
            )
        self._inbox_user = user

    def logout(self, *, everywhere: bool = False) -> None:
        """End this session (``everywhere``: every session and saved login of the account)."""
        if self.session is None:
            return
        try:
            logout = LogoutRequest(keep_resume=self.keep_resume, everywhere=everywhere)
            self._ask(keys.registry_logout(self.realm), logout, OkReply, "logout")
        finally:
            self.session = None
            self._undeclare()

    # -- private messages

    def send_private(self, user: str, text: str) -> bool:
        """Send an end-to-end encrypted message; True if delivered live, False if kept for later."""
        if self.session is None:
            raise NotLoggedIn("log in first")
        where = self._ask(
            keys.registry_directory(self.realm),
            UserKeysRequest(user=user),
            UserKeysReply,
            f"message {user}",
        )
        if where.online and where.session_box_keys:
            inbox = keys.user_inbox(self.realm, user)
            for box_key in where.session_box_keys:
                message = self._encrypt(user, box_key, text)
                self.z.put(inbox, self.session.seal(inbox, message), **qos.of(keys.user_inbox))
            return True
        if where.mailbox_key is None:
            raise NotFound(f"{user} has never logged in: there is no key to encrypt to yet")
        self._ask(
            keys.registry_directory(self.realm),
            MailboxDeposit(message=self._encrypt(user, where.mailbox_key, text)),
            OkReply,
            f"message {user}",
        )
        return False

    def _encrypt(self, user: str, to_key: bytes, text: str) -> PrivateMessage:
        assert self.session is not None
        return seal_private(self.session, user, to_key, text)

    def _open_private(self, message: PrivateMessage, *, kept: bool) -> PrivateText | None:
        if self.session is None:
            return None
        return open_private(self.session, self._mailbox, message, kept=kept)

    def _on_inbox(self, sample: zenoh.Sample) -> None:
        with self._inbox_lock:
            if self.session is None:  # logging in: read it once the session is ours
                if len(self._early) < _EARLY_INBOX_MAX:
                    self._early.append(sample)
                return
        self._deliver(sample)

    def _deliver(self, sample: zenoh.Sample) -> None:
        try:
            principal, message = self.verifier.open(
                str(sample.key_expr), sample.payload, (PrivateMessage, KickNotice)
            )
        except (AuthError, MessageError) as exc:
            log.warning("ignored an inbox message: %s", exc)
            return
        if isinstance(message, KickNotice):
            if principal.has("admin"):
                self.on_kicked(message)
            return
        # The sender's box key must be the one in their own signed token.
        if message.sender != principal.user or message.sender_box_key != principal.token.box_key:
            log.warning("ignored a private message whose sender does not match its session")
            return
        opened = self._open_private(message, kept=False)
        if opened is not None:
            self.on_private(opened)
