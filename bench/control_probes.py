"""bench_control_latency's raw Zenoh round trips, beside the control loop at the same rate.

rtt_probe: between two client sessions of the world's process; path_probe:
over the loop's own path (the world's session -> the controllers' process,
which echoes on PING/PONG, see bench.control_child -> back).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

from bench.control_timing import WORLD
from common.service import close_session, open_session
from common.zconfig import NetworkOptions


class Sink(Protocol):
    def append(self, value: float, /) -> None: ...


def ping_until(
    send: Callable[[], None], got: threading.Event, stop: threading.Event, out: Sink
) -> None:
    """``send`` a ping at 50 Hz until ``stop``; note the RTT whenever ``got`` is set within 1 s."""
    time.sleep(0.5)  # let the subscriptions reach the router before measuring
    while not stop.is_set():
        got.clear()
        start = time.monotonic()
        send()
        if got.wait(1.0):
            out.append(time.monotonic() - start)
        stop.wait(0.02)


def rtt_probe(options: NetworkOptions, stop: threading.Event, out: Sink) -> None:
    """Raw Zenoh round trips between two client sessions through the router, at 50 Hz."""
    a = open_session(options, wait=10)
    b = open_session(options, wait=10)
    ping, pong = f"{WORLD}/rtt/ping", f"{WORLD}/rtt/pong"
    got = threading.Event()
    echo = b.declare_subscriber(ping, lambda s: b.put(pong, s.payload))
    back = a.declare_subscriber(pong, lambda _s: got.set())
    try:
        ping_until(lambda: a.put(ping, b"x" * 64), got, stop, out)
    finally:
        echo.undeclare()
        back.undeclare()
        close_session(a)
        close_session(b)


PING, PONG = f"{WORLD}/rtt/path/ping", f"{WORLD}/rtt/path/pong"


def path_probe(z: Any, stop: threading.Event, out: Sink) -> None:
    """Raw Zenoh round trips over the control loop's own path, at 50 Hz.


    From the world's session through the router to the controllers' process
    (whose session echoes, see ``child``) and back: the same processes, hops
    and express publishers as a sample and the command answering it, without
    the controllers' and the world's work.
    """
    got = threading.Event()
    ping = z.declare_publisher(PING, express=True)
    back = z.declare_subscriber(PONG, lambda _s: got.set())
    try:
        ping_until(lambda: ping.put(b"x" * 64), got, stop, out)
    finally:
        back.undeclare()
        ping.undeclare()
