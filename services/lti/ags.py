"""Grade passback (LTI Assignment and Grade Services): a score posted to a line item.

An access token comes from the platform's token endpoint by OAuth2
``client_credentials`` with a JWT client assertion the tool signs with its own
key (services/lti/tool_key.py), scope ``.../scope/score``; it is kept until
shortly before it expires. A score is POSTed to ``<lineitem>/scores`` as
``application/vnd.ims.lis.v1.score+json``. :class:`Passback` works through the
outbox (services/lti/store.py): a 5xx, a timeout or a refused connection is
retried with backoff (5 s, doubling, at most 10 min apart), for as long as it
takes; a 4xx other than 401 is the platform's "no" and is not tried again; a
401 fetches a new token once. Each step is logged in words.
"""

from __future__ import annotations

import json
import logging
import secrets
import threading
import time
import urllib.error
import urllib.request
from datetime import UTC, datetime
from urllib.parse import urlencode, urlsplit, urlunsplit

import jwt

from common.worker import Worker
from services.lti.config import LtiConfig, Platform
from services.lti.store import LtiStore, Outgoing
from services.lti.tool_key import ToolKey

log = logging.getLogger("wart.lti")

SCORE_SCOPE = "https://purl.imsglobal.org/spec/lti-ags/scope/score"
SCORE_TYPE = "application/vnd.ims.lis.v1.score+json"
HTTP_TIMEOUT_S = 10.0
FIRST_RETRY_S = 5.0
MAX_RETRY_S = 600.0


class PassbackError(Exception):
    """A post that failed; ``again``: worth another try later (5xx, timeout, no answer)."""

    def __init__(self, message: str, *, again: bool, unauthorized: bool = False) -> None:
        super().__init__(message)
        self.again = again
        self.unauthorized = unauthorized


def scores_url(lineitem: str) -> str:
    """``<lineitem>/scores``, the line item's query string kept after the path."""
    parts = urlsplit(lineitem)
    return urlunsplit(parts._replace(path=parts.path.rstrip("/") + "/scores"))


def score_body(out: Outgoing) -> dict[str, object]:
    given = min(max(out.score, 0.0), out.maximum)  # a grade book takes 0..maximum
    return {
        "userId": out.subject,
        "scoreGiven": round(given, 4),
        "scoreMaximum": out.maximum,
        "activityProgress": "Completed",
        "gradingProgress": "FullyGraded",
        "timestamp": datetime.fromtimestamp(out.graded_at, UTC).isoformat(timespec="milliseconds"),
        "comment": f"wart submission {out.submission}",
    }


def _http(request: urllib.request.Request, what: str) -> bytes:
    try:
        with urllib.request.urlopen(request, timeout=HTTP_TIMEOUT_S) as answer:
            return bytes(answer.read(1 << 20))
    except urllib.error.HTTPError as exc:
        body = exc.read(300).decode("utf-8", "replace").strip()
        words = f"{what}: the platform answered {exc.code} {exc.reason}" + (
            f" ({body})" if body else ""
        )
        raise PassbackError(words, again=exc.code >= 500, unauthorized=exc.code == 401) from None
    except (urllib.error.URLError, TimeoutError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise PassbackError(f"{what}: no answer from the platform ({reason})", again=True) from None


class TokenSource:
    """Access tokens per platform, fetched with a signed client assertion and kept."""

    def __init__(self, key: ToolKey) -> None:
        self.key = key
        self._tokens: dict[tuple[str, str], tuple[str, float]] = {}
        self._lock = threading.Lock()

    def assertion(self, platform: Platform) -> str:
        now = int(time.time())
        claims = {
            "iss": platform.client_id,
            "sub": platform.client_id,
            "aud": platform.auth_token_url,
            "iat": now,
            "exp": now + 300,
            "jti": secrets.token_urlsafe(16),
        }
        return jwt.encode(
            claims, self.key.private, algorithm="RS256", headers={"kid": self.key.kid}
        )

    def token(self, platform: Platform, *, fresh: bool = False) -> str:
        ident = (platform.issuer, platform.client_id)
        with self._lock:
            kept = self._tokens.get(ident)
        if kept is not None and not fresh and kept[1] > time.time() + 30:
            return kept[0]
        form = urlencode(
            {
                "grant_type": "client_credentials",
                "client_assertion_type": "urn:ietf:params:oauth:client-assertion-type:jwt-bearer",
                "client_assertion": self.assertion(platform),
                "scope": SCORE_SCOPE,
            }
        ).encode()
        request = urllib.request.Request(
            platform.auth_token_url,
            data=form,
            headers={"Content-Type": "application/x-www-form-urlencoded"},
            method="POST",
        )
        raw = _http(request, "the access token")
        try:
            answer = json.loads(raw)
            token, ttl = str(answer["access_token"]), float(answer.get("expires_in", 3600))
        except (ValueError, KeyError, TypeError):
            raise PassbackError(
                "the access token: the platform's answer has no access_token", again=True
            ) from None
        with self._lock:
            self._tokens[ident] = (token, time.time() + ttl)
        return token


class Passback:
    """Posts the outbox's scores, one thread, retrying with backoff; nothing posted twice."""

    def __init__(self, config: LtiConfig, store: LtiStore, key: ToolKey) -> None:
        self.config = config
        self.store = store
        self.tokens = TokenSource(key)
        self._wake = threading.Event()
        self._worker = Worker(self._run, "passback", wake=self._wake.set)

    def start(self) -> None:
        self._worker.start()

    def stop(self, timeout: float) -> None:
        self._worker.stop(timeout)

    def wake(self) -> None:
        self._wake.set()

    def _run(self) -> None:
        while not self._worker.stopping.is_set():
            for out in self.store.due(time.time()):
                if self._worker.stopping.is_set():
                    return
                self._post_one(out)
            following = self.store.next_due()
            wait = MAX_RETRY_S if following is None else max(0.0, following - time.time())
            self._wake.wait(min(wait, MAX_RETRY_S))
            self._wake.clear()

    def _post_one(self, out: Outgoing) -> None:
        platform = self.config.platform(out.issuer, out.client_id)
        if platform is None:
            self.store.failed(out.submission, f"platform {out.issuer} is no longer configured")
            log.error("score of %s not posted: platform %s is no longer in the config",
                      out.submission, out.issuer)  # fmt: skip
            return
        try:
            self.post(platform, out)
        except PassbackError as exc:
            if exc.again:
                delay = min(FIRST_RETRY_S * 2**out.attempts, MAX_RETRY_S)
                self.store.retry(out.submission, str(exc), time.time() + delay)
                log.warning("score of %s for %s (%s) not posted yet: %s; trying again in %.0f s",
                            out.submission, out.user, out.assignment, exc, delay)  # fmt: skip
            else:
                self.store.failed(out.submission, str(exc))
                log.error("score of %s for %s (%s) refused by the platform, not retried: %s",
                          out.submission, out.user, out.assignment, exc)  # fmt: skip
            return
        self.store.sent(out.submission)
        log.info("score of %s for %s (%s) posted to %s: %g of %g",
                 out.submission, out.user, out.assignment, platform.issuer,
                 score_body(out)["scoreGiven"], out.maximum)  # fmt: skip

    def post(self, platform: Platform, out: Outgoing) -> None:
        body = json.dumps(score_body(out)).encode()
        for fresh in (False, True):
            token = self.tokens.token(platform, fresh=fresh)
            request = urllib.request.Request(
                scores_url(out.lineitem),
                data=body,
                headers={"Content-Type": SCORE_TYPE, "Authorization": f"Bearer {token}"},
                method="POST",
            )
            try:
                _http(request, "the score")
                return
            except PassbackError as exc:
                if not exc.unauthorized or fresh:
                    raise
                log.info("the platform refused the kept access token: fetching a new one")
