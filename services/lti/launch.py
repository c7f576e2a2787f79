"""LTI 1.3's OIDC login and resource-link launch, checked (no network but the JWKS fetch).

The LMS starts a launch by sending the browser to the tool's login URL with
``iss``, ``login_hint``, ``target_link_uri`` (and ``lti_message_hint``,
``client_id``, ``lti_deployment_id``). The tool answers with a redirect to the
platform's auth URL carrying a fresh ``state`` and ``nonce``, both kept here,
short-lived and good once. The platform posts back ``id_token`` + ``state``:
the token is a JWT the platform signed; it is checked, in this order:
state (known, unused, not expired), the platform (issuer and client), the
signature against the platform's JWKS (cached; fetched again for an unknown
``kid``), ``aud`` holds our client id and ``azp`` is it, ``exp``/``iat``, the
nonce (the one this login sent, never used before: a replayed token is
refused), the deployment id (configured), the message type
(``LtiResourceLinkRequest``) and ``version`` 1.3.0. The first check that fails
says, in words, what was wrong; nothing is written anywhere before all pass.

PyJWT does the JWT work (signature, exp/iat/aud/iss, its JWKS client with the
key cache); the LTI rules above are ours: a few lines each (docs/COURSES.md,
"LTI 1.3", says why not PyLTI1p3).
"""

from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlencode

import jwt

from services.lti.config import LtiConfig, Platform

LTI = "https://purl.imsglobal.org/spec/lti/claim/"
AGS_CLAIM = "https://purl.imsglobal.org/spec/lti-ags/claim/endpoint"
STATE_TTL_S = 300.0  # a login's state and nonce: the platform answers in seconds
NONCE_KEEP_S = 3600.0  # used nonces are remembered at least as long as a token lives
LEEWAY_S = 30.0  # clock skew allowed on exp/iat (as every service allows ±30 s)
MAX_TOKEN_AGE_S = 3600.0  # an id_token issued longer ago than this is refused
JWKS_CACHE_S = 300.0
# An unknown kid fetches the key set again (a platform rolled its key over), at most
# once per this many seconds: tokens with made-up kids cannot make us hammer the LMS.
JWKS_COOLDOWN_S = 5.0

ROLE_TEACHER = ("#Instructor", "#TeachingAssistant", "#Administrator", "#ContentDeveloper")
ROLE_STUDENT = ("#Learner", "#Student")


class LaunchError(Exception):
    """A launch refused: ``status`` for the HTTP answer, ``message`` for the person."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass(frozen=True)
class Launch:
    """A verified resource-link launch: who, from where, into what."""

    platform: Platform
    subject: str
    name: str
    email: str
    roles: tuple[str, ...]
    deployment_id: str
    context_id: str
    context_label: str
    resource_link: str
    custom: dict[str, str]
    lineitem: str | None  # the AGS line item URL, if the platform offers grade passback
    ags_scopes: tuple[str, ...]

    @property
    def role(self) -> str | None:
        """The course role: teacher, student, or None (a role the lab does not map)."""
        if any(r.endswith(ROLE_TEACHER) for r in self.roles):
            return "teacher"
        if any(r.endswith(ROLE_STUDENT) for r in self.roles):
            return "student"
        return None


@dataclass
class _Pending:
    platform: Platform
    nonce: str
    target: str
    expires: float


@dataclass
class OneTime:
    """States of logins in progress and nonces used: each good once, then forgotten late."""

    states: dict[str, _Pending] = field(default_factory=dict)
    nonces: dict[str, float] = field(default_factory=dict)  # nonce -> forget after
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, state: str, pending: _Pending) -> None:
        with self.lock:
            now = time.time()
            for s in [s for s, p in self.states.items() if p.expires < now]:
                del self.states[s]
            for n in [n for n, t in self.nonces.items() if t < now]:
                del self.nonces[n]
            self.states[state] = pending

    def take(self, state: str) -> _Pending | None:
        with self.lock:
            pending = self.states.pop(state, None)
        if pending is None or pending.expires < time.time():
            return None
        return pending

    def use_nonce(self, nonce: str, until: float) -> bool:
        """True the first time ``nonce`` is used; False for a replay."""
        with self.lock:
            if nonce in self.nonces:
                return False
            self.nonces[nonce] = until
            return True

    def seen_nonce(self, nonce: str) -> bool:
        with self.lock:
            return nonce in self.nonces


class Launcher:
    """The tool side of the OIDC login and the launch, for the platforms in the config."""

    def __init__(self, config: LtiConfig) -> None:
        self.config = config
        self.once = OneTime()
        self._jwks: dict[str, jwt.PyJWKClient] = {}
        self._jwks_lock = threading.Lock()

    # -- the OIDC login initiation

    def login(self, params: dict[str, str]) -> str:
        """The URL of the platform's auth endpoint to send the browser to."""
        issuer = params.get("iss", "")
        if not issuer:
            raise LaunchError(400, "the login has no 'iss' (the LMS's issuer)")
        client_id = params.get("client_id") or None
        platform = self.config.platform(issuer, client_id)
        if platform is None:
            raise LaunchError(
                400,
                f"this tool knows no platform {issuer}"
                + (f" with client id {client_id}" if client_id else "")
                + ": add it to the lti config",
            )
        hint = params.get("login_hint", "")
        if not hint:
            raise LaunchError(400, "the login has no 'login_hint'")
        deployment = params.get("lti_deployment_id")
        if deployment and deployment not in platform.deployment_ids:
            raise LaunchError(403, f"deployment {deployment!r} of {issuer} is not configured")
        target = params.get("target_link_uri") or self.config.launch_url
        state, nonce = secrets.token_urlsafe(24), secrets.token_urlsafe(24)
        self.once.add(state, _Pending(platform, nonce, target, time.time() + STATE_TTL_S))
        query = {
            "scope": "openid",
            "response_type": "id_token",
            "response_mode": "form_post",
            "prompt": "none",
            "client_id": platform.client_id,
            "redirect_uri": self.config.launch_url,
            "login_hint": hint,
            "state": state,
            "nonce": nonce,
        }
        if params.get("lti_message_hint"):
            query["lti_message_hint"] = params["lti_message_hint"]
        sep = "&" if "?" in platform.auth_login_url else "?"
        return f"{platform.auth_login_url}{sep}{urlencode(query)}"

    # -- the launch

    def _jwks_client(self, platform: Platform) -> jwt.PyJWKClient:
        with self._jwks_lock:
            client = self._jwks.get(platform.key_set_url)
            if client is None:
                client = jwt.PyJWKClient(
                    platform.key_set_url,
                    cache_keys=True,
                    lifespan=int(JWKS_CACHE_S),
                    timeout=10,
                    cooldown_duration=JWKS_COOLDOWN_S,
                )
                self._jwks[platform.key_set_url] = client
            return client

    def _signing_key(self, platform: Platform, token: str) -> Any:
        try:
            header = jwt.get_unverified_header(token)
        except jwt.PyJWTError as exc:
            raise LaunchError(400, f"the id_token is not a JWT: {exc}") from None
        if header.get("alg") != "RS256":
            raise LaunchError(401, f"the id_token is signed with {header.get('alg')!r}, not RS256")
        kid = header.get("kid")
        if not kid:
            raise LaunchError(401, "the id_token's header names no key (kid)")
        try:
            # PyJWKClient fetches the key set again when the kid is not in its cache.
            return self._jwks_client(platform).get_signing_key(kid).key
        except jwt.PyJWKClientConnectionError as exc:
            raise LaunchError(
                502, f"the platform's key set ({platform.key_set_url}) could not be fetched: {exc}"
            ) from None
        except jwt.PyJWKClientError:
            raise LaunchError(
                401,
                f"the id_token was signed with key {kid!r}, which the platform's key set "
                f"({platform.key_set_url}) does not have",
            ) from None

    def launch(self, id_token: str, state: str) -> Launch:
        """The verified launch, or LaunchError saying what was wrong."""
        if not state:
            raise LaunchError(400, "the launch has no 'state': start it from the LMS again")
        if not id_token:
            raise LaunchError(400, "the launch has no 'id_token'")
        pending = self.once.take(state)
        if pending is None:
            raise LaunchError(
                400,
                "the launch's state is unknown, used or expired (a launch is good once, "
                f"within {STATE_TTL_S:g} s of its login): start it from the LMS again",
            )
        platform = pending.platform
        key = self._signing_key(platform, id_token)
        try:
            claims = jwt.decode(
                id_token,
                key,
                algorithms=["RS256"],
                audience=platform.client_id,
                issuer=platform.issuer,
                leeway=LEEWAY_S,
                options={"require": ["exp", "iat", "iss", "aud", "sub", "nonce"]},
            )
        except jwt.InvalidSignatureError:
            raise LaunchError(401, "the id_token's signature does not verify") from None
        except jwt.ExpiredSignatureError:
            raise LaunchError(401, "the id_token has expired (exp is past)") from None
        except jwt.InvalidAudienceError:
            raise LaunchError(
                401, f"the id_token is not for this tool (aud is not {platform.client_id!r})"
            ) from None
        except jwt.InvalidIssuerError:
            raise LaunchError(401, f"the id_token was not issued by {platform.issuer}") from None
        except jwt.ImmatureSignatureError:
            raise LaunchError(401, "the id_token is issued in the future (iat)") from None
        except jwt.MissingRequiredClaimError as exc:
            raise LaunchError(401, f"the id_token has no {exc.claim!r} claim") from None
        except jwt.PyJWTError as exc:
            raise LaunchError(401, f"the id_token is not valid: {exc}") from None
        return self._lti_checks(platform, pending, claims)

    def _lti_checks(self, platform: Platform, pending: _Pending, c: dict[str, Any]) -> Launch:
        aud = c["aud"]
        azp = c.get("azp")
        if ((isinstance(aud, list) and len(aud) > 1) or azp is not None) and azp != (
            platform.client_id
        ):
            raise LaunchError(401, f"the id_token's azp is {azp!r}, not {platform.client_id!r}")
        if not isinstance(c["iat"], int | float) or time.time() - c["iat"] > MAX_TOKEN_AGE_S:
            raise LaunchError(401, "the id_token was issued too long ago (iat)")
        nonce = str(c["nonce"])
        if self.once.seen_nonce(nonce):
            raise LaunchError(401, "the id_token's nonce was used before: a replayed launch")
        if nonce != pending.nonce:
            raise LaunchError(401, "the id_token's nonce is not the one this login sent")
        version = c.get(LTI + "version")
        if version != "1.3.0":
            raise LaunchError(400, f"LTI version {version!r}: this tool speaks LTI 1.3.0")
        kind = c.get(LTI + "message_type")
        if kind != "LtiResourceLinkRequest":
            raise LaunchError(400, f"message type {kind!r}: this tool takes LtiResourceLinkRequest")
        deployment = c.get(LTI + "deployment_id")
        if not isinstance(deployment, str) or deployment not in platform.deployment_ids:
            raise LaunchError(
                403, f"deployment {deployment!r} of {platform.issuer} is not configured here"
            )
        context = _table(c.get(LTI + "context"))
        link = _table(c.get(LTI + "resource_link"))
        if not link.get("id"):
            raise LaunchError(400, "the launch names no resource link (resource_link.id)")
        roles = c.get(LTI + "roles")
        if not isinstance(roles, list):
            raise LaunchError(400, "the launch has no roles claim")
        ags = _table(c.get(AGS_CLAIM))
        lineitem = ags.get("lineitem")
        scope = ags.get("scope")
        scopes: list[Any] = scope if isinstance(scope, list) else []
        # Used up only now, when everything else holds: a refused token spends nothing
        # but its state (which was taken above and is good once anyway).
        if not self.once.use_nonce(nonce, time.time() + NONCE_KEEP_S):
            raise LaunchError(401, "the id_token's nonce was used before: a replayed launch")
        custom = _table(c.get(LTI + "custom"))
        return Launch(
            platform=platform,
            subject=str(c["sub"])[:255],
            name=str(c.get("name") or c.get("given_name") or "")[:200],
            email=str(c.get("email") or "")[:200],
            roles=tuple(str(r) for r in roles),
            deployment_id=deployment,
            context_id=str(context.get("id") or ""),
            context_label=str(context.get("label") or ""),
            resource_link=str(link["id"]),
            custom={str(k): str(v) for k, v in custom.items()},
            lineitem=str(lineitem) if isinstance(lineitem, str) and lineitem else None,
            ags_scopes=tuple(str(s) for s in scopes),
        )


def _table(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}
