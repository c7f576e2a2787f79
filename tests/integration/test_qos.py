"""What people read survives a link swamped by frames (common/qos.py), through a real router.

A context, a viewer and a recorder subscribe to their world's frames; on a
busy machine the router's queue to such a process fills with them, and a
message at the frames' priority with Zenoh's default congestion control is
dropped with them. A student's print that never reached the page was seen so.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from common import keys, qos
from common.service import close_session, open_session
from tests.conftest import Router, wait_for

FLOOD_S = 3.0
FRAME = bytes(32_000)  # a big world's frame
LINES = 60


@pytest.fixture
def sessions(router: Router) -> Iterator[tuple[zenoh.Session, zenoh.Session]]:
    sender = open_session(router.options(), wait=10.0)
    receiver = open_session(router.options(), wait=10.0)
    try:
        yield sender, receiver
    finally:
        close_session(receiver)
        close_session(sender)


def lines_through_a_flood(
    router: Router, sender: zenoh.Session, receiver: zenoh.Session, line_qos: dict[str, Any]
) -> tuple[list[bytes], list[bytes], int]:
    """Lines put with ``line_qos`` among frames flooding a slow subscriber: (sent, got, frames)."""
    frames_key = keys.world_frame(router.realm, "w1")
    lines_key = keys.ctx_output(router.realm, "arena")
    got: list[bytes] = []
    seen = [0]
    flooding = threading.Event()
    flooding.set()

    def on_frame(_sample: zenoh.Sample) -> None:
        seen[0] += 1
        if flooding.is_set():
            time.sleep(0.002)  # a busy process: 2 ms a frame, far below the flood's rate

    receiver.declare_subscriber(frames_key, on_frame)
    receiver.declare_subscriber(lines_key, lambda s: got.append(bytes(s.payload.to_bytes())))
    frames = sender.declare_publisher(frames_key)  # the frames' own QoS: Zenoh's default
    time.sleep(0.5)  # both subscriptions known to the router
    sent: list[bytes] = []
    end = time.monotonic() + FLOOD_S
    put = 0
    while time.monotonic() < end:
        frames.put(FRAME)
        put += 1
        if put % 40 == 0 and len(sent) < LINES:
            line = f"line {len(sent)}".encode()
            sender.put(lines_key, line, **line_qos)
            sent.append(line)
    flooding.clear()
    # Every line the router still holds arrives once the subscriber catches up;
    # a dropped one never does, so wait for the frames to stop arriving instead.
    last = -1
    while last != seen[0]:
        last = seen[0]
        time.sleep(1.0)
    return sent, got, put


def test_lines_among_a_flood_of_frames_all_arrive_in_order(
    router: Router, sessions: tuple[zenoh.Session, zenoh.Session]
) -> None:
    sender, receiver = sessions
    sent, got, frames = lines_through_a_flood(router, sender, receiver, qos.of(keys.ctx_output))
    assert len(sent) == LINES, f"only {len(sent)} lines sent among {frames} frames"
    wait_for(lambda: len(got) == len(sent), 30, "every line")
    assert got == sent


def test_the_flood_does_drop_what_has_the_frames_qos(
    router: Router, sessions: tuple[zenoh.Session, zenoh.Session]
) -> None:
    # The same flood with the lines at the frames' priority and congestion control:
    # some are lost. Without this the test above could pass on a link that never
    # filled, proving nothing.
    sender, receiver = sessions
    sent, got, frames = lines_through_a_flood(router, sender, receiver, {})
    assert len(got) < len(sent), f"all {len(sent)} lines arrived among {frames} frames"
