"""A flood of idle connections gets the tool's 503, not a thread each; it serves again after."""

from __future__ import annotations

import socket
import time
import urllib.error
import urllib.request
from typing import Any

import pytest

from services.lti import web


def _tool_server() -> web.ToolServer:
    """The tool's HTTP server on a free port, started: only its JWKS path is asked."""
    launcher: Any = object()  # the JWKS path asks nothing of it
    server = web.ToolServer("127.0.0.1", 0, launcher, lambda launch: None, {"keys": []})  # type: ignore[arg-type,return-value]
    server.start()
    return server


def _refused_with_503(server: web.ToolServer) -> bool:
    """Whether one more connection from 127.0.0.1 asking for the JWKS gets the 503."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as more:
        more.sendall(b"GET /lti/jwks HTTP/1.1\r\nHost: x\r\n\r\n")
        return more.recv(200).startswith(b"HTTP/1.1 503 Service Unavailable")


def test_idle_connections_beyond_the_cap_are_refused_and_service_resumes(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(web, "MAX_IN_FLIGHT", 2)
    server = _tool_server()
    idle = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(2)]
    try:
        assert _refused_with_503(server)
    finally:
        for s in idle:
            s.close()

    def jwks() -> bytes:
        with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/lti/jwks", timeout=5) as r:
            return bytes(r.read())

    # The idle ones gone, their slots come back (the server sees them close at its next read).
    for _ in range(100):
        try:
            assert jwks() == b'{"keys": []}'
            break
        except urllib.error.HTTPError as exc:
            assert exc.code == 503
            time.sleep(0.05)
    else:
        raise AssertionError("the tool never served again after the idle connections closed")
    server.stop(5)


def test_sixty_four_idle_connections_from_one_address_leave_the_tool_to_everyone_else() -> None:
    server = _tool_server()
    idle = [socket.create_connection(("127.0.0.1", server.port)) for _ in range(64)]
    try:
        # Another browser (another loopback address) is served at once...
        with socket.create_connection(
            ("127.0.0.1", server.port), timeout=5, source_address=("127.0.0.2", 0)
        ) as other:
            other.sendall(b"GET /lti/jwks HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            status = other.recv(200).split(b"\r\n")[0]
            assert b" 200 " in status, status
        # ...while the flooding address gets the 503 beyond its share.
        assert _refused_with_503(server)
    finally:
        for s in idle:
            s.close()
        server.stop(5)
