"""A login sent while no registry is routed to asks again for a moment (LabClient).

The query's network is faked here (what is tested is when the client asks
again); the real race, a login in the instant a registry comes back, runs
through a router in tests/integration/test_viewer_logins.py.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from types import SimpleNamespace

import nacl.signing

from common.auth import LOGIN_FIND_S
from common.client.lab_client import LabClient


@dataclass
class FakeZenoh:
    """``get`` ends at once with nothing ``unrouted`` times, then as ``then`` says."""

    unrouted: int
    then: str  # "answer", "silent" (waits out its timeout) or "nowhere" (ends at once, always)
    asked: list[float] = field(default_factory=list)

    def get(self, key: str, payload: bytes, timeout: float, source_info: object) -> list[object]:
        self.asked.append(timeout)
        if len(self.asked) <= self.unrouted or self.then == "nowhere":
            return []
        if self.then == "silent":
            time.sleep(timeout)
            return []
        return [SimpleNamespace(ok=SimpleNamespace(payload=b"the registry's reply"))]

    def declare_querier(self, key: str) -> object:
        return SimpleNamespace(id=None)


def _client(z: FakeZenoh) -> LabClient:
    registry = nacl.signing.SigningKey.generate().verify_key
    client = LabClient(z, "lab", bytes(registry))  # type: ignore[arg-type]
    client._source_info = lambda key: None  # type: ignore[method-assign]
    return client


def test_a_registry_routed_to_a_moment_later_gets_the_login() -> None:
    z = FakeZenoh(unrouted=3, then="answer")
    answers = _client(z)._find_registry("lab/registry/login", b"sealed", wait=30.0)
    assert answers == [b"the registry's reply"]
    assert len(z.asked) == 4


def test_no_registry_at_all_is_said_within_the_find_window() -> None:
    z = FakeZenoh(unrouted=0, then="nowhere")
    started = time.monotonic()
    assert _client(z)._find_registry("lab/registry/login", b"sealed", wait=30.0) == []
    took = time.monotonic() - started
    assert took <= LOGIN_FIND_S + 0.5, f"said after {took:.1f} s, not within the window"
    assert len(z.asked) >= 2, "asked only once: a registry back a moment later would be missed"


def test_a_registry_that_took_the_query_is_not_asked_twice() -> None:
    # Frozen or swamped: its password check may still be queued; asking again would queue another.
    z = FakeZenoh(unrouted=0, then="silent")
    assert _client(z)._find_registry("lab/registry/login", b"sealed", wait=0.4) == []
    assert len(z.asked) == 1


def test_the_asker_never_waits_longer_than_its_wait() -> None:
    z = FakeZenoh(unrouted=2, then="silent")
    started = time.monotonic()
    _client(z)._find_registry("lab/registry/login", b"sealed", wait=1.0)
    assert time.monotonic() - started < 1.3
    assert all(t <= 1.0 for t in z.asked)
