"""A service's worker queue under a burst: late answers rather than wasted work."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest
import zenoh

from common import keys
from common.keys import AliveKind
from common.messages import ErrorReply, Message, OkReply, decode
from common.service import Service
from tests.conftest import Router, wait_for


class SlowService(Service):
    """One worker whose handler blocks until the test lets it go."""

    kind = AliveKind.REGISTRY

    def __init__(self, session: zenoh.Session, realm: str, stale_after: float) -> None:
        super().__init__(session, realm, "slowregistry")
        self.stale_after = stale_after
        self.release = threading.Event()
        self.handled: list[str] = []
        self.key = keys.registry_login(realm)  # where a class's logins queue

    def on_start(self) -> None:
        self.serve(self.key, self.on_query, workers=1, stale_after=self.stale_after)

    def on_query(self, query: zenoh.Query) -> Message:
        name = bytes(query.payload).decode() if query.payload is not None else ""
        self.handled.append(name)
        self.release.wait(30)
        return OkReply()


@pytest.fixture
def slow(zsession: zenoh.Session, router: Router) -> Iterator[SlowService]:
    service = SlowService(zsession, router.realm, stale_after=0.5).start()
    yield service
    service.release.set()
    service.stop()


def _ask(session: zenoh.Session, key: str, name: str, out: dict[str, object]) -> None:
    replies = list(session.get(key, payload=name.encode(), timeout=20))
    answers = [decode(r.ok.payload.to_bytes(), (OkReply, ErrorReply)) for r in replies if r.ok]
    out[name] = answers[0] if answers else None


def test_a_query_that_waited_past_its_askers_patience_is_told_busy_not_worked(
    slow: SlowService, zsession: zenoh.Session
) -> None:
    answers: dict[str, object] = {}
    first = threading.Thread(target=_ask, args=(zsession, slow.key, "first", answers))
    first.start()
    wait_for(lambda: slow.handled == ["first"], 10, "the worker takes the first query")
    second = threading.Thread(target=_ask, args=(zsession, slow.key, "second", answers))
    second.start()
    # The second waits behind the first for longer than stale_after (0.5 s): by the time
    # the worker is free its asker is assumed gone, so it must not cost a handler run.
    threading.Event().wait(1.0)
    slow.release.set()
    first.join(20)
    second.join(20)
    assert isinstance(answers["first"], OkReply)
    busy = answers["second"]
    assert isinstance(busy, ErrorReply) and busy.code == "rate_limited"
    assert "busy" in busy.message
    assert slow.handled == ["first"]
    # And the queue works normally again: a fresh query is handled.
    _ask(zsession, slow.key, "third", answers)
    assert isinstance(answers["third"], OkReply)
    assert slow.handled == ["first", "third"]
