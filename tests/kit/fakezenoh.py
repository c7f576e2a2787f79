"""Just enough of a Zenoh session to drive a WorldChannel and its links without a router:
publishers keep their puts, subscribers' callbacks are called by hand with a FakeSample."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any


class FakePayload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


class FakeSample:
    def __init__(self, data: bytes) -> None:
        self.payload = FakePayload(data)


class FakePublisher:
    """Keeps every put; with ``hold_s``, each put takes that long (others queue behind it)."""

    def __init__(self, key: str = "", hold_s: float = 0.0) -> None:
        self.key, self.hold_s = key, hold_s
        self.puts: list[bytes] = []
        self._lock = threading.Lock()

    def put(self, payload: bytes) -> None:
        if self.hold_s:
            time.sleep(self.hold_s)  # a put in flight: others queue behind it meanwhile
        with self._lock:
            self.puts.append(payload)

    def undeclare(self) -> None:
        pass


class FakeSession:
    """Records publishers and subscribers' callbacks by key expression."""

    def __init__(self, hold_s: float = 0.0) -> None:
        self.hold_s = hold_s
        self.publishers: dict[str, FakePublisher] = {}
        self.callbacks: dict[str, Callable[[Any], None]] = {}

    def declare_publisher(self, key: str, **_: Any) -> FakePublisher:
        self.publishers[key] = FakePublisher(key, self.hold_s)
        return self.publishers[key]

    def declare_subscriber(self, key: str, callback: Callable[[Any], None]) -> FakePublisher:
        self.callbacks[key] = callback
        return FakePublisher(key)  # only undeclare() is used
