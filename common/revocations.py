"""How a service learns revoked sessions: the registry's signed list, at start and live.

Revocations are signed by the registry's key (the same key that signs
tokens), so nobody else can revoke a session by publishing on the key. A
service creates one :class:`RevocationFeed` next to its Verifier; every
revocation goes into the Verifier before ``on_revoked`` runs (a context drops
the session's member there).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import nacl.exceptions
import nacl.signing
import zenoh

from common import keys
from common.ask import WrongReply, ask
from common.auth import Verifier
from common.lab_errors import LabError
from common.messages import (
    MessageError,
    Revocation,
    RevocationList,
    RevocationsRequest,
    SignedRevocations,
    decode,
)

log = logging.getLogger("wart.revocations")


def open_revocations(registry_key: bytes, payload: object) -> RevocationList:
    """The RevocationList in ``payload`` if the registry signed it; MessageError otherwise."""
    return verified_revocations(registry_key, decode(payload, SignedRevocations))


def verified_revocations(registry_key: bytes, signed: SignedRevocations) -> RevocationList:
    """The RevocationList ``signed`` holds if the registry signed it; MessageError otherwise."""
    try:
        nacl.signing.VerifyKey(registry_key).verify(signed.body, signed.signature)
    except nacl.exceptions.BadSignatureError:
        raise MessageError("revocation list not signed by this lab's registry") from None
    return decode(signed.body, RevocationList)


def is_ban(revocation: Revocation) -> bool:
    """Whether a revocation bans its user: the registry kicks each session of a banned
    account "... by <admin>: banned until <end>: <reason>" (services/registry/admin.py)."""
    return revocation.kicked and ": banned until " in revocation.reason


class RevocationFeed:
    """Keeps a Verifier's revocations in step with the registry."""

    def __init__(
        self,
        session: zenoh.Session,
        realm: str,
        registry_key: bytes,
        verifier: Verifier,
        on_revoked: Callable[[Revocation], None] = lambda _r: None,
    ) -> None:
        self._session = session
        self._key = keys.registry_revocations(realm)
        self._registry_key = registry_key
        self._verifier = verifier
        self._on_revoked = on_revoked
        self._stop = threading.Event()
        self.loaded = threading.Event()  # set once the registry's full list was received
        self._sub = session.declare_subscriber(self._key, self._on_sample)
        self._thread = threading.Thread(target=self._load, name="revocations", daemon=True)
        self._thread.start()

    def _apply(self, revoked: RevocationList) -> None:
        for rev in revoked.revoked:
            self._verifier.revoke(rev.session_id, rev.expires_at)
            try:
                self._on_revoked(rev)
            except Exception:
                log.exception("error handling the revocation of a session of %s", rev.user)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        try:
            self._apply(open_revocations(self._registry_key, sample.payload))
        except MessageError as exc:
            log.warning("ignored a revocation message: %s", exc)

    def _load(self) -> None:
        """Ask the registry for every revocation in force; retry until it answers."""
        delay = 0.2
        while not self._stop.is_set():
            try:
                signed = ask(
                    self._session,
                    self._key,
                    RevocationsRequest(),
                    SignedRevocations,
                    what="revocations",
                    timeout=3.0,
                )
                self._apply(verified_revocations(self._registry_key, signed))
                self.loaded.set()
                return
            except (MessageError, WrongReply) as exc:  # not the registry's, or not signed
                log.warning("ignored a revocation list: %s", exc)
            except LabError as exc:  # no registry yet, or the session closing
                log.debug("revocation query failed: %s", exc)
            self._stop.wait(delay)
            delay = min(delay * 2, 5.0)

    def close(self) -> None:
        self._stop.set()
        try:
            self._sub.undeclare()
        except Exception as exc:
            log.debug("revocation subscriber: %s", exc)
