"""How a service (room, agent context, runner, world) logs in and stays logged in.

Services log in with an Ed25519 identity key registered for their account
(``LabClient.login_with_key``) and renew the session before it expires.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import nacl.signing
import zenoh

from common import keys
from common.auth import Session, load_identity_key, parse_public_key
from common.client.lab_client import LabClient
from common.lab_errors import LabError, NotLoggedIn, RateLimited, RegistryUnreachable
from common.messages import LoginVouch
from common.zconfig import NetworkOptions

log = logging.getLogger("wart.client")


class ServiceLogin:
    """A service's session, logged in with its identity key and renewed before it expires.

    ``session`` always returns the current one; seal with it at send time.
    """

    def __init__(
        self,
        client: LabClient,
        user: str,
        identity: nacl.signing.SigningKey,
        ttl: float = 24 * 3600.0,
    ) -> None:
        self.client = client
        self.user = user
        self.identity = identity
        self.ttl = ttl
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def session(self) -> Session:
        session = self.client.session
        if session is None:
            raise NotLoggedIn(f"service account {self.user} is not logged in")
        return session

    def login(self, wait: float = 60.0) -> Session:
        """Log in, retrying while no registry answers (it may start after us)."""
        deadline = time.monotonic() + wait
        delay = 0.2
        while True:
            try:
                self.client.login_with_key(self.user, self.identity, ttl=self.ttl)
                break
            except (RegistryUnreachable, RateLimited) as exc:
                if time.monotonic() > deadline:
                    raise
                log.info("service login as %s: %s; retrying", self.user, exc)
                self._stop.wait(delay)
                delay = min(delay * 2, 2.0)
        if self._thread is None:
            self._thread = threading.Thread(target=self._renew, name="renew", daemon=True)
            self._thread.start()
        return self.session

    def _renew(self) -> None:
        while not self._stop.is_set():
            session = self.client.session
            remaining = (session.token.expires_at - time.time()) if session else 0.0
            if self._stop.wait(max(1.0, remaining * 0.8)):
                return
            try:
                self.client.login_with_key(self.user, self.identity, ttl=self.ttl)
            except LabError as exc:
                log.warning("could not renew the session of %s: %s", self.user, exc)

    def close(self) -> None:
        self._stop.set()
        self.client.close()


def add_world_args(p: Any) -> None:
    """What every world process (engine, bridge) takes: ``--watchdog-ms``, and
    ``--user/--identity``, optional unlike other services'.

    With them the world logs in as a service account with the ``world``
    permission and advertises its token, so contexts can grant MAC leases;
    without them it keeps working, every command an Ed25519 envelope.
    """
    p.add_argument(
        "--watchdog-ms",
        type=float,
        default=300.0,
        help="stop a robot whose commands stop for this long (default 300)",
    )
    p.add_argument("--user", help="the world's service account (optional; enables MAC leases)")
    p.add_argument("--identity", type=Path, help="the service account's Ed25519 key file")


def world_login(
    session: zenoh.Session, realm: str, registry_key: bytes | None, user: str | None, key: Any
) -> ServiceLogin | None:
    """The world's logged-in ServiceLogin, or None without ``--user``; RuntimeError if it fails."""
    if not user:
        return None
    if key is None or registry_key is None:
        raise RuntimeError("--user needs --identity and --registry-key")
    credentials = ServiceCredentials(registry_key, user, load_identity_key(Path(key)))
    login = credentials.login(session, realm, "world")
    if not login.session.has("world"):
        login.close()
        raise RuntimeError(f"account {user} lacks the 'world' permission")
    return login


@dataclass(frozen=True)
class ServiceCredentials:
    """What a service needs to log in: the pinned registry key, its account, its key.

    Every service process (rooms, agent contexts, runners) builds one from its
    command line and logs in through it, so the checks and the error words are
    the same everywhere.
    """

    registry_key: bytes
    user: str
    identity: nacl.signing.SigningKey

    @classmethod
    def from_options(
        cls, registry_key_hex: str | None, user: str, identity_file: Path, what: str
    ) -> ServiceCredentials:
        """Check the flags; ValueError with a message naming the flag that is wrong."""
        keys.check_ident("user", user)
        if not registry_key_hex:
            raise ValueError(f"--registry-key is required: the {what} must know whom to trust")
        return cls(parse_public_key(registry_key_hex), user, load_identity_key(identity_file))

    @classmethod
    def of_service(
        cls, kind: str, args: argparse.Namespace, options: NetworkOptions
    ) -> ServiceCredentials:
        """A service's ``--name`` checked as a ``kind`` id, then its account's credentials
        from the flags cli.add_account_arguments adds (ValueError as from_options)."""
        keys.check_ident(kind, args.name)
        return cls.from_options(options.registry_key, args.user, args.identity, kind)

    def login(
        self, session: zenoh.Session, realm: str, what: str, wait: float = 120.0
    ) -> ServiceLogin:
        """Log in as the service account (waiting for the registry), renewed until stopped."""
        client = LabClient(session, realm, self.registry_key, presence=False)
        login = ServiceLogin(client, self.user, self.identity)
        try:
            login.login(wait=wait)
        except LabError as exc:
            raise RuntimeError(f"{what} could not log in as {self.user}: {exc}") from None
        return login


def vouch_for(session: Session, realm: str, address: str) -> Callable[[bytes], bytes]:
    """A gateway's voucher for one person's login (``LabClient(voucher=...)``).

    Given the new session's key, it seals a LoginVouch with the gateway's own
    session, saying the login comes from ``address`` (the browser's address as
    the gateway sees it). The registry then throttles that address, not the
    gateway's whole Zenoh session; it honours the vouch only from ``vouch``.
    """
    if not address or len(address) > 128 or not address.isprintable():
        raise ValueError(f"a vouched address is 1 to 128 printable characters, not {address!r}")
    key = keys.registry_login(realm)
    return lambda session_key: session.seal(
        key, LoginVouch(address=address, session_key=session_key)
    )
