"""Browsers log in here: the viewer's own lab, or one its admin listed in the labs file.

One :class:`~viewers.web.lab_links.LabRouterLink` (a Zenoh session) per lab router,
shared by everyone logged in through it; one
:class:`~viewers.web.live.LiveConnection` per logged-in browser.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
from collections.abc import Callable
from pathlib import Path

import zenoh

from common import lab_errors
from common.auth import LOGIN_WAIT_S, parse_public_key
from common.client import lab_client as lab
from common.client.lab_address import LabAddress
from common.client.service_login import ServiceCredentials, ServiceLogin, vouch_for
from common.lab_errors import LabError
from common.service import close_session, open_session
from common.zconfig import NetworkOptions
from viewers.web.adapters import LoginError, LoginUnavailable, plain_error
from viewers.web.lab_links import LabRouterLink, load_labs
from viewers.web.live import LiveConnection
from viewers.web.live_world import QUERY_TIMEOUT

log = logging.getLogger("wart.viewer.live")

LABS_FILE = "labs.json"


class MailboxClaims:
    """Page users' mailbox keys, derived after their logins: one at a time, at nice 19.

    Each is an argon2id run (~75 ms of a core, 64 MiB). Run as they came, a class
    logging in at once would hold 60 of them, 3.8 GB, beside the registry's checks;
    one low-priority thread takes them in turn behind everything else.
    """

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue[tuple[lab.LabClient, str] | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name="mailbox-claims", daemon=True)
        self._thread.start()

    def submit(self, client: lab.LabClient, password: str) -> None:
        self._jobs.put((client, password))

    def close(self) -> None:
        self._jobs.put(None)

    def _run(self) -> None:
        with contextlib.suppress(OSError, AttributeError):  # Linux: a thread's own nice
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)
        while (job := self._jobs.get()) is not None:
            client, password = job
            if client.session is None:
                continue  # logged out meanwhile
            try:
                kept = client.claim_mailbox(password)
            except LabError as exc:
                log.info("a mailbox was not claimed: %s", exc)
                continue
            if kept:
                log.info("%d kept messages for %s", len(kept), client.user)


class GatewayLogin:
    """The viewer's own service account (role ``gateway``), logged in in the background.

    With it the viewer vouches, at each browser's login, for the address its
    socket saw; the registry then throttles failed logins per browser address
    instead of per viewer (docs/SECURITY.md "Failed logins"). Until it is logged
    in (the registry may start after the viewer), logins go unvouched.
    """

    def __init__(self, session: zenoh.Session, realm: str, credentials: ServiceCredentials) -> None:
        self.session = session
        self.realm = realm
        self.credentials = credentials
        self.login: ServiceLogin | None = None
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._run, name="gateway-login", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            login = self.credentials.login(self.session, self.realm, "viewer")
        except (LabError, RuntimeError) as exc:
            log.warning("the viewer's account %s cannot log in: %s", self.credentials.user, exc)
            return
        if not login.session.has("vouch"):
            log.warning("account %s lacks 'vouch' (role gateway): logins go unvouched", login.user)
        if self._closed.is_set():
            login.close()
            return
        self.login = login

    def voucher(self, address: str) -> Callable[[bytes], bytes] | None:
        login = self.login
        if login is None or login.client.session is None:
            return None
        try:
            return vouch_for(login.session, self.realm, address)
        except ValueError as exc:
            log.info("not vouching for %r: %s", address, exc)
            return None

    def close(self) -> None:
        self._closed.set()
        if self.login is not None:
            self.login.close()


class LiveConnector:
    """Logs browsers in to labs: the viewer's own, or one listed in the admin's labs file."""

    def __init__(
        self,
        own_session: zenoh.Session,
        own_address: LabAddress,
        own_registry_key: bytes | str | None,
        *,
        data_dir: Path | None = None,
        timeout: float = QUERY_TIMEOUT,
        login_wait: float = LOGIN_WAIT_S,
        gateway: GatewayLogin | None = None,
    ) -> None:
        if isinstance(own_registry_key, str):
            own_registry_key = parse_public_key(own_registry_key)
        self.own_address = own_address.with_user(None)
        self.own_registry_key = own_registry_key
        self.labs_path = data_dir / LABS_FILE if data_dir else None
        self.timeout = timeout
        if not login_wait > 0:
            raise ValueError(f"login_wait must be positive, not {login_wait}")
        self.login_wait = login_wait  # how long a login waits for the registry's answer
        self._own_session = own_session
        self.gateway = gateway  # vouches for browsers' addresses to the viewer's own lab
        self._links: dict[tuple[str, int, str], LabRouterLink] = {}
        self._lock = threading.Lock()
        self._connections: list[LiveConnection] = []
        self.claims = MailboxClaims()

    def _is_own(self, address: LabAddress) -> bool:
        own = self.own_address
        if address.realm != own.realm or address.port != own.port:
            return False
        local = {"127.0.0.1", "localhost", "::1"}
        return address.host == own.host or (address.host in local and own.host in local)

    def _link(self, address: LabAddress) -> LabRouterLink:
        key = address.lab_key
        with self._lock:
            link = self._links.get(key)
            if link is not None:
                link.users += 1
                return link
        if self._is_own(address):
            if self.own_registry_key is None:
                raise LoginError(
                    "this viewer was started without --registry-key, so it cannot check "
                    "that the lab's registry is genuine; ask the lab's admin"
                )
            link = LabRouterLink(address, self._own_session, self.own_registry_key, own=True)
        else:
            known = load_labs(self.labs_path, self.own_address.realm).get(key)
            if known is None:
                where = self.labs_path or "the viewer's data directory"
                raise LoginError(
                    f"this viewer does not know the lab {address.label}: its admin must add "
                    f"it, with its registry key, to {where} (keys are never trusted blindly)"
                )
            options = NetworkOptions(
                realm=address.realm, mode="client", connect=(address.endpoint,)
            )
            try:
                session = open_session(options, wait=3.0, quiet=True)
            except ConnectionError:
                raise LoginUnavailable(
                    f"no lab router answers at {address.host}:{address.port}"
                ) from None
            link = LabRouterLink(address, session, known.registry_key, own=False)
        with self._lock:
            existing = self._links.get(key)
            if existing is not None:  # another browser opened it meanwhile: use theirs
                existing.users += 1
                if link.session is not self._own_session:
                    close_session(link.session)
                return existing
            link.users = 1
            self._links[key] = link
        return link

    def _unlink(self, link: LabRouterLink) -> None:
        with self._lock:
            link.users -= 1
            if link.users > 0 or link.own:
                return
            self._links.pop(link.address.lab_key, None)
        link.close()

    def login(
        self, address: LabAddress, user: str, password: str, via: str = "", seen_from: str = ""
    ) -> LiveConnection:
        # The mailbox key is derived after the login, at the lowest CPU priority: on
        # the lab's own cores it cost as much as the registry's check, and a class
        # logging in at once waited for both (docs/BENCHMARKS.md, the login burst).
        connection = self._open(
            address,
            lambda c: c.login(
                user, password, wait=self.login_wait, resume=True, defer_mailbox=True
            ),
            "wrong user name or password",
            via,
            seen_from,
        )
        self.claims.submit(connection.client, password)
        return connection

    def resume(
        self, address: LabAddress, token: bytes, via: str = "", seen_from: str = ""
    ) -> LiveConnection:
        """A saved login (viewers/web/saved_login.py): no password, one signature check."""
        resume = lambda c: c.resume(token, wait=self.login_wait)  # noqa: E731
        return self._open(address, resume, "", via, seen_from)

    def _open(
        self,
        address: LabAddress,
        log_in: Callable[[lab.LabClient], object],
        wrong: str,
        via: str,
        seen_from: str,
    ) -> LiveConnection:
        link = self._link(address)
        # Only our own lab's registry knows the viewer's account: elsewhere the
        # login counts against this viewer's Zenoh session, like any client's.
        voucher = None
        if link.own and self.gateway is not None and seen_from:
            voucher = self.gateway.voucher(seen_from)
        client = lab.LabClient(
            link.session,
            address.realm,
            link.registry_key,
            timeout=self.timeout,
            via=via,
            voucher=voucher,
        )
        try:
            log_in(client)
        except lab_errors.WrongCredentials as exc:
            self._unlink(link)
            # A password's refusal says nothing more; a saved login's says why it ended.
            raise LoginError(wrong or str(exc)) from None
        except ValueError as exc:  # a saved login's token that is not one at all
            self._unlink(link)
            raise LoginError(
                f"your saved login is damaged ({exc}): log in with your password"
            ) from None
        except lab_errors.RegistryKeyMismatch:
            self._unlink(link)
            raise LoginError(
                f"the registry answering at {address.label} is not the one this viewer trusts "
                "(its key differs): tell the lab's admin"
            ) from None
        except lab_errors.RegistryUnreachable:
            self._unlink(link)
            raise LoginUnavailable(
                f"the lab's registry at {address.label} does not answer: it is down or "
                "overloaded. Try again in a minute; if it keeps failing, tell the lab's staff."
            ) from None
        except lab_errors.RateLimited as exc:
            self._unlink(link)
            # The registry's own words: busy (a queue full of logins) or slowing
            # repeated failures ("try again in 8 s"); both say what to do.
            raise LoginUnavailable(f"the lab's registry says: {exc}") from None
        except lab_errors.LabError as exc:
            self._unlink(link)
            raise LoginError(str(plain_error(exc, address))) from None
        connection = LiveConnection(self, link, client, address.with_user(client.user))
        with self._lock:
            self._connections.append(connection)
        return connection

    def _closed(self, connection: LiveConnection) -> None:
        with self._lock:
            if connection in self._connections:
                self._connections.remove(connection)
        self._unlink(connection.link)

    def close(self) -> None:
        """Log everyone out and close the other labs' sessions (the viewer is stopping)."""
        self.claims.close()
        if self.gateway is not None:
            self.gateway.close()
        with self._lock:
            connections = list(self._connections)
        for connection in connections:
            connection.logout(keep_resume=True)  # the viewer stops, the person did not log out
        with self._lock:
            links = list(self._links.values())
            self._links.clear()
        for link in links:
            link.close()
