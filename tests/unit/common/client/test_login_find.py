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
import pytest

from common.auth import LOGIN_FIND_S, SessionKeys
from common.client.lab_client import LabClient
from common.lab_errors import RegistryUnreachable


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
    answers, taken = _client(z)._find_registry("lab/registry/login", b"sealed", wait=30.0)
    assert answers == [b"the registry's reply"] and taken
    assert len(z.asked) == 4


def test_no_registry_at_all_is_said_within_the_find_window() -> None:
    z = FakeZenoh(unrouted=0, then="nowhere")
    started = time.monotonic()
    assert _client(z)._find_registry("lab/registry/login", b"sealed", wait=30.0) == ([], False)
    took = time.monotonic() - started
    assert took <= LOGIN_FIND_S + 0.5, f"said after {took:.1f} s, not within the window"
    assert len(z.asked) >= 2, "asked only once: a registry back a moment later would be missed"


def test_a_registry_that_took_the_query_is_not_asked_twice() -> None:
    # Frozen or swamped: its password check may still be queued; asking again would queue another.
    z = FakeZenoh(unrouted=0, then="silent")
    assert _client(z)._find_registry("lab/registry/login", b"sealed", wait=0.4) == ([], True)
    assert len(z.asked) == 1


def test_a_swamped_registry_is_not_said_to_be_missing() -> None:
    # The user is told the registry took the login and did not answer, not "is it running?".
    z = FakeZenoh(unrouted=0, then="silent")
    with pytest.raises(RegistryUnreachable, match="took the login but did not answer in 0 s"):
        _client(z)._login_reply("lab/registry/login", b"sealed", SessionKeys(), None, wait=0.4)
    z = FakeZenoh(unrouted=0, then="nowhere")
    with pytest.raises(RegistryUnreachable, match="is it running"):
        _client(z)._login_reply("lab/registry/login", b"sealed", SessionKeys(), None, wait=0.4)


def test_the_asker_never_waits_longer_than_its_wait() -> None:
    z = FakeZenoh(unrouted=2, then="silent")
    started = time.monotonic()
    _client(z)._find_registry("lab/registry/login", b"sealed", wait=1.0)
    assert time.monotonic() - started < 1.3
    assert all(t <= 1.0 for t in z.asked)
