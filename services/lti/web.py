"""The tool's HTTP endpoints (the standard library's threaded server: a handful of requests).

    GET|POST /lti/login    OIDC login initiation -> 302 to the platform's auth URL
    POST     /lti/launch   id_token + state -> the lab's page, logged in (a cookie), or
                           an error page saying what was wrong (4xx)
    GET      /lti/jwks     the tool's public key set (the LMS checks our client assertions)
    GET      /             what to tell the LMS (the three URLs above)

What a launch does once verified is the service's (``on_launch``): this module
only speaks HTTP. A form body is at most 64 KiB; a request that takes longer
than 15 s to arrive is dropped.
"""

from __future__ import annotations

import contextlib
import html
import json
import logging
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from common.worker import Worker
from services.lti.launch import Launch, Launcher, LaunchError

log = logging.getLogger("wart.lti")

MAX_BODY = 64 * 1024


MAX_IN_FLIGHT = 64  # connections served at once; beyond, a 503 at once
MAX_PER_ADDRESS = 16  # of them from one address: one client's idle flood leaves the rest


class _Server(ThreadingHTTPServer):
    # A class clicks the link at once: the standard library's backlog of 5 connections
    # made the 6th wait for the kernel's SYN retry (1 s, 3 s, 7 s: bench/bench_lti.py).
    request_queue_size = 128
    daemon_threads = True

    def __init__(self, *args: object, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        # One thread per connection, and a slow client holds its thread (15 s a read):
        # a flood of idle connections must not grow threads without bound.
        self._slots = threading.BoundedSemaphore(MAX_IN_FLIGHT)
        self._by_address: dict[str, int] = {}
        self._lock = threading.Lock()

    def _take(self, address: str) -> str:
        """ "" if a slot is taken for ``address``; else why not."""
        with self._lock:
            if self._by_address.get(address, 0) >= MAX_PER_ADDRESS:
                return f"{MAX_PER_ADDRESS} connections from {address} at once"
            if not self._slots.acquire(blocking=False):
                return f"{MAX_IN_FLIGHT} connections at once"
            self._by_address[address] = self._by_address.get(address, 0) + 1
            return ""

    def process_request(self, request: Any, client_address: Any) -> None:
        address = str(client_address[0])
        why = self._take(address)
        if why:
            log.warning("busy: %s; %s refused", why, address)
            with contextlib.suppress(OSError):
                request.sendall(
                    b"HTTP/1.1 503 Service Unavailable\r\nRetry-After: 1\r\n"
                    b"Content-Length: 0\r\nConnection: close\r\n\r\n"
                )
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            address = str(client_address[0])
            with self._lock:
                left = self._by_address.get(address, 1) - 1
                if left > 0:
                    self._by_address[address] = left
                else:
                    self._by_address.pop(address, None)
            self._slots.release()


class Landing:
    """Where a verified launch sends the browser: a URL, and the cookies to set first."""

    def __init__(self, url: str, cookies: list[str]) -> None:
        self.url = url
        self.cookies = cookies


def page(title: str, text: str) -> bytes:
    body = (
        "<!doctype html><html><head><meta charset='utf-8'>"
        f"<title>{html.escape(title)}</title></head><body>"
        f"<h1>{html.escape(title)}</h1><p>{html.escape(text)}</p></body></html>"
    )
    return body.encode()


class ToolServer:
    def __init__(
        self,
        host: str,
        port: int,
        launcher: Launcher,
        on_launch: Callable[[Launch], Landing],
        jwks: dict[str, object],
    ) -> None:
        self.launcher = launcher
        self.on_launch = on_launch
        self.jwks = json.dumps(jwks).encode()
        tool = self

        class Handler(BaseHTTPRequestHandler):
            server_version = "wart-lti"
            timeout = 15

            def log_message(self, format: str, *args: object) -> None:
                log.debug("%s %s", self.address_string(), format % args)

            def do_GET(self) -> None:
                tool.handle(self, "GET")

            def do_POST(self) -> None:
                tool.handle(self, "POST")

        self.httpd = _Server((host, port), Handler)
        self._worker = Worker(self.httpd.serve_forever, "http", wake=self.httpd.shutdown)

    @property
    def port(self) -> int:
        return int(self.httpd.server_address[1])

    def start(self) -> None:
        self._worker.start()

    def stop(self, timeout: float) -> None:
        self._worker.stop(timeout)
        self.httpd.server_close()

    # -- requests

    def _params(self, h: BaseHTTPRequestHandler, method: str) -> dict[str, str]:
        params = dict(parse_qsl(urlsplit(h.path).query))
        if method == "POST":
            try:
                length = int(h.headers.get("Content-Length") or 0)
            except ValueError:
                raise LaunchError(400, "the request's Content-Length is not a number") from None
            if length > MAX_BODY:
                raise LaunchError(413, f"the request is over {MAX_BODY // 1024} KiB")
            kind = h.headers.get("Content-Type", "").split(";")[0].strip()
            raw = h.rfile.read(length) if length > 0 else b""
            if raw and kind != "application/x-www-form-urlencoded":
                raise LaunchError(415, "a form post (application/x-www-form-urlencoded) is needed")
            params.update(parse_qsl(raw.decode("utf-8", "replace")))
        return params

    def handle(self, h: BaseHTTPRequestHandler, method: str) -> None:
        path = urlsplit(h.path).path
        try:
            if path == "/lti/jwks" and method == "GET":
                self._send(h, 200, self.jwks, "application/json")
            elif path == "/lti/login":
                url = self.launcher.login(self._params(h, method))
                self._redirect(h, url, [])
            elif path == "/lti/launch" and method == "POST":
                params = self._params(h, method)
                launch = self.launcher.launch(params.get("id_token", ""), params.get("state", ""))
                landing = self.on_launch(launch)
                self._redirect(h, landing.url, landing.cookies)
            elif path == "/" and method == "GET":
                self._send(h, 200, self._index(), "text/html; charset=utf-8")
            else:
                raise LaunchError(404, f"nothing here ({method} {path})")
        except LaunchError as exc:
            log.warning("refused %s %s from %s: %s", method, path, h.client_address[0], exc.message)
            self._send(h, exc.status, page("LTI launch refused", exc.message), "text/html")
        except Exception:
            log.exception("%s %s failed", method, path)
            text = "the tool failed on this request (its log says why): try again"
            self._send(h, 500, page("LTI tool error", text), "text/html")

    def _index(self) -> bytes:
        c = self.launcher.config
        text = (
            f"wart's LTI 1.3 tool. Tell your LMS: login URL {c.login_url}, "
            f"launch (redirect) URL {c.launch_url}, public key set URL {c.jwks_url}."
        )
        return page("wart LTI tool", text)

    @staticmethod
    def _send(h: BaseHTTPRequestHandler, status: int, body: bytes, kind: str) -> None:
        h.send_response(status)
        h.send_header("Content-Type", kind)
        h.send_header("Content-Length", str(len(body)))
        h.send_header("Cache-Control", "no-store")
        h.end_headers()
        h.wfile.write(body)

    @staticmethod
    def _redirect(h: BaseHTTPRequestHandler, url: str, cookies: list[str]) -> None:
        h.send_response(303)  # See Other: the browser follows with a GET
        h.send_header("Location", url)
        for cookie in cookies:
            h.send_header("Set-Cookie", cookie)
        h.send_header("Cache-Control", "no-store")
        h.send_header("Content-Length", "0")
        h.end_headers()
