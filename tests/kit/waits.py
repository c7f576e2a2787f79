"""Waiting for something a process does: poll a condition, never a fixed sleep, and the
newest message on a key for the conditions to read."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import zenoh

from common.messages import Message, decode


def wait_for(
    condition: Callable[[], object], timeout: float = 10.0, what: str = "condition"
) -> object:
    """Poll ``condition`` until it returns something truthy; fail with ``what`` on timeout."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.02)


class Latest:
    """The newest decoded message on a key, and how many arrived (callback kept short)."""

    def __init__(self, session: zenoh.Session, key: str, kind: type[Message]) -> None:
        self.value: object = None
        self.count = 0
        self._lock = threading.Lock()

        def on(sample: zenoh.Sample) -> None:
            message = decode(sample.payload, kind)
            with self._lock:
                self.value = message
                self.count += 1

        self.sub = session.declare_subscriber(key, on)

    def get(self) -> object:
        with self._lock:
            return self.value
