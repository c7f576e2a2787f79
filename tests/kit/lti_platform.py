"""A fake LMS for the LTI tests: its own RSA keys and JWKS, an OIDC auth endpoint, an
OAuth2 token endpoint and an AGS score endpoint that records what it gets.

All on 127.0.0.1, a free port, a thread: no internet. It answers the tool's OIDC
redirect as a platform does, with a page whose form posts ``id_token`` and
``state`` to the tool's launch URL; ``next_claims`` says who launches and how,
and ``tamper`` lets a test spoil the token the way a bad launch would.
"""

from __future__ import annotations

import html
import json
import re
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import jwt
from cryptography.hazmat.primitives.asymmetric import rsa
from jwt.algorithms import RSAAlgorithm

from tests.kit.json_http import send_json

LTI = "https://purl.imsglobal.org/spec/lti/claim/"
AGS = "https://purl.imsglobal.org/spec/lti-ags/claim/endpoint"
CLIENT_ID = "wart-tool-1"
DEPLOYMENT = "deploy-1"
CONTEXT_ID = "ctx-42"
LEARNER = "http://purl.imsglobal.org/vocab/lis/v2/membership#Learner"
INSTRUCTOR = "http://purl.imsglobal.org/vocab/lis/v2/membership#Instructor"


def new_key() -> rsa.RSAPrivateKey:
    return rsa.generate_private_key(public_exponent=65537, key_size=2048)


@dataclass
class Launcher:
    """Who the next launch is for; the claims the platform signs."""

    sub: str = "u-1001"
    name: str = "Lea Learner"
    roles: tuple[str, ...] = (LEARNER,)
    assignment: str | None = None
    context_label: str = "ROBO101"


@dataclass
class FakePlatform:
    tool_jwks_url: str = ""
    key: rsa.RSAPrivateKey = field(default_factory=new_key)
    kid: str = "platform-key-1"
    next: Launcher = field(default_factory=Launcher)
    tamper: Callable[[dict[str, Any], dict[str, Any]], tuple[Any, str]] | None = None
    token_failures: int = 0  # the token endpoint answers 500 this many times first
    scores: list[dict[str, Any]] = field(default_factory=list)
    score_auth: list[str] = field(default_factory=list)
    tokens_issued: int = 0
    assertions: list[dict[str, Any]] = field(default_factory=list)
    last_id_token: str = ""
    jwks_fetches: int = 0

    def __post_init__(self) -> None:
        platform = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, format: str, *args: object) -> None:
                pass

            def do_GET(self) -> None:
                platform._handle(self, "GET")

            def do_POST(self) -> None:
                platform._handle(self, "POST")

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.httpd.daemon_threads = True
        self.httpd.socket.listen(128)  # a class launching at once (bench/bench_lti.py)
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()
        self.lock = threading.Lock()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.httpd.server_address[1]}"

    @property
    def lineitem(self) -> str:
        return f"{self.url}/api/lineitems/7/lineitem?type_id=1"

    def toml(self, assignment_links: dict[str, str] | None = None) -> str:
        """The [[platform]] table of the tool's config for this platform."""
        links = "".join(f'"{k}" = "{v}"\n' for k, v in (assignment_links or {}).items())
        return (
            "[[platform]]\n"
            f'issuer = "{self.url}"\n'
            f'client_id = "{CLIENT_ID}"\n'
            f'deployment_ids = ["{DEPLOYMENT}"]\n'
            f'auth_login_url = "{self.url}/auth"\n'
            f'auth_token_url = "{self.url}/token"\n'
            f'key_set_url = "{self.url}/jwks"\n'
            "score_maximum = 100\n"
            "[platform.courses]\n"
            f'"{CONTEXT_ID}" = "robotics-26"\n'
            "[platform.assignments]\n" + links
        )

    # -- what it signs

    def claims(self, nonce: str, hint: str = "") -> dict[str, Any]:
        """``hint``: the login_hint; "sub:ID" launches that user (many launches at once)."""
        who = self.next
        if hint.startswith("sub:"):
            who = Launcher(sub=hint[4:], name=hint[4:], roles=who.roles)
        now = int(time.time())
        custom = {"assignment": who.assignment} if who.assignment else {}
        return {
            "iss": self.url,
            "aud": CLIENT_ID,
            "azp": CLIENT_ID,
            "sub": who.sub,
            "exp": now + 300,
            "iat": now,
            "nonce": nonce,
            "name": who.name,
            "email": f"{who.sub}@lms.example",
            LTI + "message_type": "LtiResourceLinkRequest",
            LTI + "version": "1.3.0",
            LTI + "deployment_id": DEPLOYMENT,
            LTI + "target_link_uri": "",
            LTI + "roles": list(who.roles),
            LTI + "context": {"id": CONTEXT_ID, "label": who.context_label, "title": "Robots"},
            LTI + "resource_link": {"id": "link-1", "title": "Reach the goal"},
            LTI + "custom": custom,
            AGS: {
                "scope": [
                    "https://purl.imsglobal.org/spec/lti-ags/scope/lineitem",
                    "https://purl.imsglobal.org/spec/lti-ags/scope/score",
                ],
                "lineitem": self.lineitem,
            },
        }

    def sign(self, claims: dict[str, Any], key: Any = None, kid: str | None = None) -> str:
        return jwt.encode(
            claims, key or self.key, algorithm="RS256", headers={"kid": kid or self.kid}
        )

    # -- HTTP

    def _handle(self, h: BaseHTTPRequestHandler, method: str) -> None:
        parts = urlsplit(h.path)
        params = dict(parse_qsl(parts.query))
        body = b""
        if method == "POST":
            body = h.rfile.read(int(h.headers.get("Content-Length") or 0))
        if parts.path == "/jwks":
            with self.lock:
                self.jwks_fetches += 1
            jwk = json.loads(RSAAlgorithm.to_jwk(self.key.public_key()))
            send_json(h, 200, {"keys": [{**jwk, "kid": self.kid, "alg": "RS256", "use": "sig"}]})
        elif parts.path == "/auth":
            self._auth(h, params)
        elif parts.path == "/token" and method == "POST":
            self._token(h, dict(parse_qsl(body.decode())))
        elif parts.path.endswith("/lineitem/scores") and method == "POST":
            with self.lock:
                self.scores.append(json.loads(body))
                self.score_auth.append(h.headers.get("Authorization", ""))
                kind = h.headers.get("Content-Type", "")
            assert kind == "application/vnd.ims.lis.v1.score+json", kind
            send_json(h, 200, {})
        else:
            send_json(h, 404, {"error": "not found"})

    def _auth(self, h: BaseHTTPRequestHandler, p: dict[str, str]) -> None:
        """The OIDC auth endpoint: an auto-submitting form to the tool's launch URL."""
        if p.get("client_id") != CLIENT_ID or p.get("response_mode") != "form_post":
            send_json(h, 400, {"error": "bad auth request"})
            return
        claims = self.claims(p["nonce"], p.get("login_hint", ""))
        header: dict[str, Any] = {"kid": self.kid}
        token = ""
        if self.tamper is not None:
            claims_or_token, state = self.tamper(claims, header)
            token = claims_or_token if isinstance(claims_or_token, str) else ""
            p = {**p, "state": state or p["state"]}
        if not token:
            token = self.sign(claims, kid=header["kid"])
        self.last_id_token = token
        fields = {"id_token": token, "state": p["state"]}
        inputs = "".join(
            f'<input type="hidden" name="{k}" value="{html.escape(v)}">' for k, v in fields.items()
        )
        page = (
            f'<html><body onload="document.forms[0].submit()"><form method="post" '
            f'action="{html.escape(p["redirect_uri"])}">{inputs}</form></body></html>'
        )
        raw = page.encode()
        h.send_response(200)
        h.send_header("Content-Type", "text/html")
        h.send_header("Content-Length", str(len(raw)))
        h.end_headers()
        h.wfile.write(raw)

    def _token(self, h: BaseHTTPRequestHandler, form: dict[str, str]) -> None:
        with self.lock:
            if self.token_failures > 0:
                self.token_failures -= 1
                send_json(h, 503, {"error": "temporarily_unavailable"})
                return
        # The client assertion must be signed by the tool's key, found at its JWKS URL.
        assertion = form.get("client_assertion", "")
        signing = jwt.PyJWKClient(self.tool_jwks_url).get_signing_key_from_jwt(assertion)
        claims = jwt.decode(
            assertion, signing.key, algorithms=["RS256"], audience=f"{self.url}/token"
        )
        assert form.get("grant_type") == "client_credentials"
        assert "lti-ags/scope/score" in form.get("scope", "")
        assert claims["iss"] == claims["sub"] == CLIENT_ID
        with self.lock:
            self.assertions.append(claims)
            self.tokens_issued += 1
        send_json(h, 200, {"access_token": f"tok-{uuid.uuid4().hex}", "expires_in": 3600})


def form_fields(page: str) -> dict[str, str]:
    """The hidden inputs of the platform's auto-submitting form."""
    found = re.findall(r'name="([^"]+)" value="([^"]*)"', page)
    return {k: html.unescape(v) for k, v in found}
