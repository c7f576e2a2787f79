"""The frame path's two shortcuts through viser 1.1.1, for a class on one arena.

Measured with 100 headless sessions on a 35-robot arena (2 cores): the pump
spent 65 ms of CPU and 154 ms of wall time a tick (25 Hz needs under 40), and
each session got 8.3 frames a second. Two costs were per view and avoidable:

- **Wake-ups.** Each view's ``client.atomic()`` ends with a
  ``call_soon_threadsafe`` on viser's event loop: a write to its self-pipe, and
  a GIL hand-off to the loop thread, per browser per frame (0.5 ms each in the
  profile). :class:`HeldBuffers` holds every watching browser's buffer for the
  whole tick and wakes the loop once, for all of them.
- **Array assignment.** ``handle.batched_positions = a`` casts, compares and
  copies ``a`` twice per browser (viser cannot know the caller will not mutate
  it). A :class:`~viewers.web.prepared_frame.PreparedFrame`'s arrays are made once
  per frame and never written again, so :func:`set_shared_array` hands the
  same array to every browser's message.

Both read or write viser internals (named below). Each checks that they are
there and otherwise does what the public API does, so a viser upgrade costs
speed, not correctness.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from typing import Any

import numpy as np
import numpy.typing as npt
import viser
from viser._messages import SceneNodeUpdateMessage

log = logging.getLogger("wart.viewer.fast")


def _buffer_of(client: viser.ClientHandle) -> Any | None:
    """The client's outgoing message buffer (viser.infra.AsyncMessageBuffer), if reachable."""
    conn = getattr(client, "_websock_connection", None)
    get = getattr(conn, "get_message_buffer", None)
    if get is None:
        return None
    buffer = get()
    needed = ("atomic_start", "buffer_lock", "atomic_counter", "message_event", "event_loop")
    return buffer if all(hasattr(buffer, n) for n in needed) else None


class HeldBuffers:
    """Browsers' buffers held atomic while the pump draws their view; one wake-up per batch.

    ``hold`` is ``client.atomic()``'s start; ``done`` its end minus the wake-up
    (the buffer is sendable again at once: a loop that is awake picks it up);
    the loop is then woken once per WAKE_EVERY views and at ``release``, for
    all of them. Holding every buffer for the whole tick instead was measured
    worse: with 100 views the tick takes most of the 40 ms period, and the
    loop had only the rest to send 100 windows (11 to 18 frames a second each).
    Nested ``client.atomic()`` blocks inside still work (viser counts them).
    """

    WAKE_EVERY = 20

    def __init__(self) -> None:
        # By identity: viser's buffers are dataclasses, and their == compares every field.
        self._held: dict[int, Any] = {}
        self._to_wake: list[Any] = []

    def hold(self, client: viser.ClientHandle) -> None:
        buffer = _buffer_of(client)
        if buffer is not None and id(buffer) not in self._held:
            buffer.atomic_start()
            self._held[id(buffer)] = buffer

    def done(self, client: viser.ClientHandle) -> None:
        buffer = _buffer_of(client)
        if buffer is None or self._held.pop(id(buffer), None) is None:
            return
        # viser's atomic_end, minus its per-buffer wake-up: the counter under the lock.
        with buffer.buffer_lock:
            buffer.atomic_counter -= 1
        self._to_wake.append(buffer)
        if len(self._to_wake) >= self.WAKE_EVERY:
            self._wake_all()

    def release(self) -> None:
        for buffer in list(self._held.values()):
            with buffer.buffer_lock:
                buffer.atomic_counter -= 1
            self._to_wake.append(buffer)
        self._held = {}
        self._wake_all()

    def _wake_all(self) -> None:
        to_wake, self._to_wake = self._to_wake, []
        loops: dict[int, tuple[asyncio.AbstractEventLoop, list[Any]]] = {}
        for buffer in to_wake:
            loops.setdefault(id(buffer.event_loop), (buffer.event_loop, []))[1].append(buffer)
        for loop, buffers in loops.values():
            with contextlib.suppress(RuntimeError):  # the server stopped: nobody to send to
                loop.call_soon_threadsafe(_wake, buffers)


def _wake(buffers: list[Any]) -> None:
    for buffer in buffers:
        buffer.message_event.set()


class LoopSafeEvent(asyncio.Event):
    """An asyncio.Event whose ``set()`` from another thread wakes its waiters in its loop.

    viser 1.1.1's ``AsyncMessageBuffer.push`` calls ``message_event.set()`` from the
    thread that queues the message (the pump, a Zenoh callback) "so the value can be
    read at once". asyncio's Event is not thread-safe: that set resolves the loop's
    waiting future from the wrong thread and iterates the waiters while the loop
    changes them. Measured with 30 to 50 headless sessions per viewer on two viewer
    processes: "deque mutated during iteration" in the pump's log, and one browser
    that never received another message (its window generator waited on an event
    already marked set, so no later set woke it): its login never showed. Here a set
    from another thread marks the value at once, as viser wants, and hands the
    waking to the loop.
    """

    _home: asyncio.AbstractEventLoop

    def set(self) -> None:
        try:
            here = asyncio.get_running_loop()
        except RuntimeError:
            here = None
        if here is self._home:
            super().set()
            return
        self._value = True  # what viser reads synchronously
        with contextlib.suppress(RuntimeError):  # the loop is closed: nobody waits
            self._home.call_soon_threadsafe(self._set_in_loop)

    def _set_in_loop(self) -> None:
        self._value = False  # so asyncio's own set() wakes every waiter
        super().set()


def make_loop_safe(client: viser.ClientHandle) -> bool:
    """Give the client's message buffer a :class:`LoopSafeEvent`; False if unreachable.

    The event object is kept (its class changed, its waiters kept): viser's window
    generator may already be waiting on it.
    """
    buffer = _buffer_of(client)
    event = getattr(buffer, "message_event", None)
    if buffer is None or type(event) is not asyncio.Event:
        return isinstance(event, LoopSafeEvent)
    event._home = buffer.event_loop  # type: ignore[attr-defined]
    event.__class__ = LoopSafeEvent
    return True


def set_shared_arrays(handle: Any, arrays: dict[str, npt.NDArray[Any]]) -> None:
    """``handle.<prop> = array`` for each, with no copy, in ONE update message.

    The arrays must never be written again (a PreparedFrame's are not). One
    message for positions and orientations together halves what viser's event
    loop serialises per browser (its buffer still coalesces: the message's
    redundancy key names both properties). The handle's own state points at
    the arrays too (what a test or a redraw reads back). A removed handle is
    left alone, as viser's setter would refuse it.
    """
    impl = getattr(handle, "_impl", None)
    props = getattr(impl, "props", None)
    api = getattr(impl, "api", None)
    queue = getattr(api, "_queue_scene_message", None)
    usable = impl is not None and props is not None and queue is not None
    for prop, array in arrays.items():
        current = getattr(props, prop, None) if usable else None
        if not isinstance(current, np.ndarray) or current.dtype != array.dtype:
            usable = False  # a viser we do not know, or a cast to make: its own setter
    if not usable or impl is None or queue is None:
        for prop, array in arrays.items():
            setattr(handle, prop, array)
        return
    if impl.removed:
        return
    for prop, array in arrays.items():
        setattr(props, prop, array)
    queue(SceneNodeUpdateMessage(impl.name, dict(arrays)))


def browser_address(client: viser.ClientHandle) -> str:
    """The browser's network address as this viewer's socket sees it ("" if unknown).

    Read from viser's websocket server (``_viser_server._websock_server._live_connections``,
    websockets' ``remote_address``): viser 1.1.1 has no public way. It is what the
    viewer vouches for at login (the registry throttles each address apart); a
    header the browser writes (X-Forwarded-For) is never read.
    """
    server = getattr(getattr(client, "_viser_server", None), "_websock_server", None)
    connections = getattr(server, "_live_connections", None)
    connection = connections.get(client.client_id) if isinstance(connections, dict) else None
    remote = getattr(connection, "remote_address", None)
    if isinstance(remote, tuple) and remote and isinstance(remote[0], str):
        return remote[0][:128]
    return ""


def browser_cookies(client: viser.ClientHandle) -> str:
    """The Cookie header of the browser's websocket handshake ("" if none or unknown).

    A browser sends the page's cookies with it (same origin; SameSite=Strict ones
    never from another site's page).
    """
    return handshake_header(client, "Cookie")


def browser_origin(client: viser.ClientHandle) -> str:
    """The Origin of the browser's websocket handshake: where the page came from.

    Written by the browser, never by a script: ``https://...`` means the page was
    served over HTTPS (behind a TLS proxy), so its cookies may be Secure.
    """
    return handshake_header(client, "Origin")


def handshake_header(client: viser.ClientHandle, name: str) -> str:
    """A header of the browser's websocket handshake ("" if none or unknown).

    Read where browser_address reads (viser 1.1.1 keeps the websockets connection,
    whose ``request`` is the handshake).
    """
    server = getattr(getattr(client, "_viser_server", None), "_websock_server", None)
    connections = getattr(server, "_live_connections", None)
    connection = connections.get(client.client_id) if isinstance(connections, dict) else None
    request = getattr(connection, "request", None)
    headers = getattr(request, "headers", None)
    if headers is None:
        return ""
    try:
        return str(headers.get(name, ""))[:8192]
    except Exception:  # a headers object we do not know
        return ""


def drop_every_page(server: viser.ViserServer) -> int:
    """Cut every page's socket now, without a closing handshake; how many were cut.

    For a viewer that stops: viser's own stop closes each socket politely, and a page
    still busy taking frames held that stop for its whole wait (6 s), its students
    waiting as long for the next viewer. A cut page reconnects at once (viser's
    client does); one that reaches this viewer before its listener closes is given
    no session (WebViewer._connected) and comes again.
    """
    websock = getattr(server, "_websock_server", None)
    loop = getattr(websock, "_background_event_loop", None)
    connections = getattr(websock, "_live_connections", None)
    if loop is None or not isinstance(connections, dict):
        return 0
    cut = 0
    for connection in tuple(connections.values()):
        transport = getattr(connection, "transport", None)
        if transport is not None:
            loop.call_soon_threadsafe(transport.abort)
            cut += 1
    return cut


def _cut_opening_sockets(loop: asyncio.AbstractEventLoop) -> None:
    """In the server's loop: cut each socket still in its opening handshake (websockets'
    ``Server.conn_handler`` tasks, not yet in viser's table of pages)."""
    for task in asyncio.all_tasks(loop):
        coro = task.get_coro()
        if getattr(coro, "__qualname__", "") != "Server.conn_handler":
            continue
        frame = getattr(coro, "cr_frame", None)
        connection = frame.f_locals.get("connection") if frame is not None else None
        transport = getattr(connection, "transport", None)
        if transport is not None:
            transport.abort()


def stop_dropping_pages(server: viser.ViserServer, every_s: float = 0.05) -> None:
    """``server.stop()``, every page's socket cut first and again until the stop is done.

    websockets' stop waits for every accepted socket: a page's, and one still in its
    opening handshake, which Chromium opens ahead of need and may send nothing on
    for seconds. One such socket held viser's stop for its whole wait (1 + 5 s):
    eight pages of a class made a real viewer process take 6 s to exit, their
    students waiting as long. The pages' sockets are cut (:func:`drop_every_page`),
    and so are the opening ones, until the stop is done.
    """
    websock = getattr(server, "_websock_server", None)
    loop = getattr(websock, "_background_event_loop", None)
    stopped = threading.Event()

    def cut_until_stopped() -> None:
        while True:
            with contextlib.suppress(RuntimeError):  # the loop has closed: all done
                drop_every_page(server)
                if loop is not None:
                    loop.call_soon_threadsafe(_cut_opening_sockets, loop)
            if stopped.wait(every_s):
                return

    cutter = threading.Thread(target=cut_until_stopped, name="drop-pages", daemon=True)
    cutter.start()
    try:
        server.stop()
    finally:
        stopped.set()
        cutter.join(1.0)
