"""The viewer's shortcuts through viser: a message queued from another thread wakes its browser."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator

import pytest

from viewers.web.viser_fast import LoopSafeEvent


@pytest.fixture
def loop() -> Iterator[asyncio.AbstractEventLoop]:
    """An event loop in its own thread, asleep with nothing scheduled (viser's, between frames)."""
    loop = asyncio.new_event_loop()
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    yield loop
    loop.call_soon_threadsafe(loop.stop)
    thread.join(5)
    loop.close()


def _loop_safe(loop: asyncio.AbstractEventLoop) -> asyncio.Event:
    async def make() -> asyncio.Event:
        event = asyncio.Event()
        event._home = loop  # type: ignore[attr-defined]
        event.__class__ = LoopSafeEvent  # what make_loop_safe does to viser's buffer
        return event

    return asyncio.run_coroutine_threadsafe(make(), loop).result(5)


def _waiter(loop: asyncio.AbstractEventLoop, event: asyncio.Event) -> threading.Event:
    """A coroutine in the loop that waits for the event, then clears it (viser's generator)."""
    woke = threading.Event()
    waiting = threading.Event()

    async def wait() -> None:
        waiting.set()
        await event.wait()
        event.clear()
        woke.set()

    asyncio.run_coroutine_threadsafe(wait(), loop)
    assert waiting.wait(5)
    return woke


def test_a_set_from_another_thread_wakes_the_waiting_browser(
    loop: asyncio.AbstractEventLoop,
) -> None:
    event = _loop_safe(loop)
    for _ in range(50):  # every frame, not just the first
        woke = _waiter(loop, event)
        event.set()  # from this thread, as viser's push() does from the pump's
        assert event.is_set() or woke.is_set()  # readable at once, as viser wants
        assert woke.wait(5), "the browser's sender was never woken"


def test_sets_racing_the_loop_never_leave_a_waiter_asleep(loop: asyncio.AbstractEventLoop) -> None:
    event = _loop_safe(loop)
    stop = threading.Event()

    def hammer() -> None:
        while not stop.is_set():
            event.set()

    threads = [threading.Thread(target=hammer) for _ in range(2)]
    for t in threads:
        t.start()
    try:
        for _ in range(200):
            assert _waiter(loop, event).wait(5), "a waiter stayed asleep"
    finally:
        stop.set()
        for t in threads:
            t.join(5)


def test_plain_asyncio_event_set_from_another_thread_does_not_wake_the_loop(
    loop: asyncio.AbstractEventLoop,
) -> None:
    """Why the class exists: viser 1.1.1 sets a plain Event from the pump's thread."""
    event = asyncio.run_coroutine_threadsafe(_make_plain(), loop).result(5)
    woke = _waiter(loop, event)
    event.set()
    assert not woke.wait(1.0), "asyncio changed: a foreign set now wakes the loop"
    loop.call_soon_threadsafe(lambda: None)  # any later wake-up runs the waiter
    assert woke.wait(5)


async def _make_plain() -> asyncio.Event:
    return asyncio.Event()
