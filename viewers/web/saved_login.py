"""A saved login in the browser: the registry's resume token kept in an HttpOnly cookie.

After a password login the page gets a cookie holding the lab's address and the
registry's resume token (services/registry/resume.py); when the page is loaded
again (a reload, a new tab) the browser sends it with the websocket handshake and
the viewer logs it in again without a password check.

No script ever holds the token. The viewer sets and deletes the cookie from its own
HTTP response: the page gets a hidden image whose address is a one-time *ticket*
(random, good for TICKET_S), and the viewer's web server answers that address with
the ``Set-Cookie`` the ticket stands for. The cookie is HttpOnly (a script in the
page, an injected one included, cannot read it), SameSite=Strict (another site's
page cannot make the browser send it), Secure when the page came over HTTPS (its
websocket's Origin says so), path /, and lasts as long as the token. The person's
"Log out" deletes it and revokes the token; closing the page does neither.

viser 1.1.1 has no hook for its HTTP answers: :meth:`CookieDesk.install` wraps the
``process_request`` of the websockets server that serves the page (read from a
live connection). A viser without it saves no login (the password is asked at each
load) and says so in the log.
"""

from __future__ import annotations

import http
import logging
import secrets
import threading
import time
from typing import Any

import viser
from websockets.datastructures import Headers
from websockets.http11 import Response

from common.client.lab_address import LabAddress
from common.client.resume_cookie import PREFIX, cookie_name, cookie_value
from common.messages import MessageError, ResumeGrant, SignedResume, decode

log = logging.getLogger("wart.viewer.saved_login")

TICKET_PATH = "wart-saved-login/"
TICKET_S = 60.0  # a ticket not fetched by then is gone (the page fetches it at once)
MAX_TICKETS = 10_000  # outstanding at once; the oldest go first


def set_cookie(name: str, value: str, max_age: int, *, secure: bool) -> str:
    """The ``Set-Cookie`` value that keeps (max_age 0: deletes) one saved login."""
    if not name.startswith(PREFIX) or not all(c.isalnum() or c in "_-." for c in name + value):
        raise ValueError("a saved-login cookie is base64url text only")
    cookie = f"{name}={value}; Path=/; Max-Age={max(0, int(max_age))}; SameSite=Strict; HttpOnly"
    return cookie + ("; Secure" if secure else "")


def saved_login_cookie(address: LabAddress, token: bytes | None, *, secure: bool) -> str:
    """The ``Set-Cookie`` that saves ``token`` for ``address``'s lab (None: forgets it)."""
    name = cookie_name(address)
    if token is None:
        return set_cookie(name, "", 0, secure=secure)
    try:
        ends = decode(decode(token, SignedResume).grant, ResumeGrant).expires_at
    except MessageError:
        return set_cookie(name, "", 0, secure=secure)
    return set_cookie(name, cookie_value(address, token), int(ends - time.time()), secure=secure)


class CookieDesk:
    """One-time tickets for the viewer's HTTP server to answer with a ``Set-Cookie``."""

    def __init__(self, ticket_s: float = TICKET_S) -> None:
        self.ticket_s = ticket_s
        self._tickets: dict[str, tuple[str, float]] = {}  # ticket -> (Set-Cookie, made at)
        self._lock = threading.Lock()
        self._installed: set[int] = set()

    def ticket(self, set_cookie_value: str) -> str:
        """A new ticket for this ``Set-Cookie``: good once, for ``ticket_s``."""
        now = time.monotonic()
        ticket = secrets.token_urlsafe(24)
        with self._lock:
            for old in [t for t, (_, at) in self._tickets.items() if now - at > self.ticket_s]:
                del self._tickets[old]
            while len(self._tickets) >= MAX_TICKETS:
                del self._tickets[next(iter(self._tickets))]
            self._tickets[ticket] = (set_cookie_value, now)
        return ticket

    def redeem(self, ticket: str) -> str | None:
        """The ``Set-Cookie`` the ticket stands for, once; None if unknown or too old."""
        with self._lock:
            found = self._tickets.pop(ticket, None)
        if found is None or time.monotonic() - found[1] > self.ticket_s:
            return None
        return found[0]

    def html(self, set_cookie_value: str, serial: int) -> str:
        """A hidden image whose fetch sets the cookie (``serial`` makes each one new)."""
        ticket = self.ticket(set_cookie_value)
        return (
            f'<!-- {serial} --><img src="{TICKET_PATH}{ticket}" alt="" '
            'style="display:none" referrerpolicy="no-referrer">'
        )

    def answer(self, path: str) -> Response | None:
        """The HTTP answer to a ticket's address; None if ``path`` is not one."""
        head = path.partition("?")[0]
        where = head.rfind("/" + TICKET_PATH)
        if where < 0:
            return None
        found = self.redeem(head[where + 1 + len(TICKET_PATH) :])
        headers = Headers()
        headers["Cache-Control"] = "no-store"
        headers["Content-Length"] = "0"
        if found is None:
            log.info(
                "a page fetched a saved-login ticket that is used or older than %.0f s: "
                "that browser keeps the login it had",
                self.ticket_s,
            )
            return Response(http.HTTPStatus.NOT_FOUND, "Not Found", headers, b"")
        forgets = "Max-Age=0;" in found
        log.debug("a page's saved login %s", "deleted" if forgets else "stored in its cookie")
        headers["Set-Cookie"] = found
        return Response(http.HTTPStatus.NO_CONTENT, "No Content", headers, b"")

    def install(self, server: viser.ViserServer, client_id: int) -> bool:
        """Answer tickets in the web server that serves ``client_id``'s page; False if not."""
        ws = getattr(server, "_websock_server", None)
        connections = getattr(ws, "_live_connections", None)
        connection = connections.get(client_id) if isinstance(connections, dict) else None
        http_server: Any = getattr(connection, "server", None)
        if http_server is None or not hasattr(http_server, "process_request"):
            return False
        with self._lock:
            if id(http_server) in self._installed:
                return True
            self._installed.add(id(http_server))
        served = http_server.process_request

        def process_request(conn: Any, request: Any) -> Any:
            answer = self.answer(str(getattr(request, "path", "")))
            if answer is not None:
                return answer
            return served(conn, request) if served is not None else None

        http_server.process_request = process_request
        # websockets logs every HTTP answer but 101 as "connection rejected (...)": for a
        # ticket that reads like a failure to an operator, and answer() has said it in words.
        logging.getLogger("websockets.server").addFilter(_TICKET_ANSWERS_UNLOGGED)
        return True


class _TicketAnswersUnlogged(logging.Filter):
    """Drops websockets' "connection rejected" line for a ticket's cookie (only they get 204)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() != "connection rejected (204 No Content)"


_TICKET_ANSWERS_UNLOGGED = _TicketAnswersUnlogged()
