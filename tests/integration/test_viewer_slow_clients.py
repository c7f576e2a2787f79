"""A stalled browser gets fewer, current frames and never slows the others (issue 22).

A real WebViewer (viser server, frame pump) on the in-memory lab's 1,000-robot
arena, and real websocket clients speaking viser's protocol
(tests/kit/viser_client.py): each logs in through the GUI and joins the arena.
One of them then stops reading its socket. The world's source does not matter
here (the demo lab's frames stand for the engine's); what is under test is the
viewer's sending side.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.kit.viser_client import RobotFrame, ViserClient, demo_lab_viewer, run_in_thread
from viewers.web.app import NOTSENT_LOWAT, WRITE_HIGH, WebViewer
from viewers.web.demo_lab import DemoLab

ROBOTS = 1000
STALLED_FRAMES = 100  # frames the others receive while one client reads nothing
# The stalled client's own kernel receive buffer: a browser behind a slow link, where
# bytes wait in the network, not in its kernel (Linux doubles it: 32 KiB, one frame).
CLIENT_RCVBUF = 16 * 1024
# What a client's asyncio transport reads in one go (asyncio's selector transports
# read 256 KiB at a time): bytes the stalled client's library may already hold.
CLIENT_READ_CHUNK = 256 * 1024


@pytest.fixture
def viewer(tmp_path: Path) -> Iterator[WebViewer]:
    with demo_lab_viewer(DemoLab("Test lab", robots=ROBOTS, rate=50.0), tmp_path / "viewer") as app:
        yield app


@dataclass
class Stall:
    good: int  # frames the two others received while one client was stalled
    other: int
    backlog: list[tuple[int, int]]  # (viser messages, socket buffer bytes) at each frame
    stale: int  # frames the stalled client read, once resumed, before a current one
    frame_bytes: int


async def _stall_and_resume(viewer: WebViewer) -> Stall:
    url = f"ws://127.0.0.1:{viewer.port}"
    good, other, stalled = (ViserClient(url, n) for n in ("good", "other", "stalled"))
    clients = (good, other, stalled)
    try:
        await good.connect()
        await other.connect()
        # max_queue=1: the websocket library stops reading the socket at once.
        await stalled.connect(max_queue=1, rcvbuf=CLIENT_RCVBUF)
        for client, user in zip(clients, ("ana", "ben", "ana"), strict=True):
            await client.log_in(user, f"{user}-pw")
            await client.join("arena")
        stalled_id = max(viewer.sessions)  # the last to connect
        stalled.stall()
        start_good, start_other, start_bytes = good.frames, other.frames, good.bytes
        backlog: list[tuple[int, int]] = []

        def sample(_frame: RobotFrame) -> None:
            # On every frame the good client gets: what waits for the stalled one.
            found = viewer.send_backlog(stalled_id)
            assert found is not None, "the stalled client was dropped"
            backlog.append(found)

        good.on_frame = sample
        await good.wait_for(lambda: good.frames - start_good >= STALLED_FRAMES, 240)
        await other.wait_for(lambda: other.frames - start_other >= STALLED_FRAMES, 240)
        good.on_frame = None
        # A frame on the wire (positions and orientations of 1,000 robots, framing).
        frame_bytes = (good.bytes - start_bytes) // max(1, good.frames - start_good)

        # Frames drawn from now on are "current"; what the stalled client reads
        # before the first of them is its backlog.
        current: set[bytes] = set()
        good.on_frame = lambda f: current.add(f.positions.tobytes())
        received: list[bytes] = []
        stalled.on_frame = lambda f: received.append(f.positions.tobytes())
        stalled.resume()
        await stalled.wait_for(lambda: any(r in current for r in received), 240)
        stale = next(i for i, r in enumerate(received) if r in current)
        return Stall(
            good.frames - start_good, other.frames - start_other, backlog, stale, frame_bytes
        )
    finally:
        for client in clients:
            await client.close()


def test_a_stalled_client_gets_current_frames_and_never_slows_the_others(
    viewer: WebViewer,
) -> None:
    seen = run_in_thread(_stall_and_resume(viewer))
    # The others kept receiving frames while one client read nothing (the waits above).
    assert seen.good >= STALLED_FRAMES and seen.other >= STALLED_FRAMES
    # What waits for the stalled client stays bounded the whole time: viser keeps the
    # newest value of each scene property (a handful of messages), and the socket's
    # user-space buffer holds at most one frame beyond its high-water mark.
    backlog, frame_bytes = seen.backlog, seen.frame_bytes
    assert len(backlog) >= STALLED_FRAMES and frame_bytes > 0
    assert max(messages for messages, _ in backlog) <= 20, backlog
    assert max(buffered for _, buffered in backlog) <= WRITE_HIGH + 2 * frame_bytes, backlog
    # When it reads again it is shown the current world after a few frames, not the
    # 100 it missed (before the send queue was limited: 125 to 149 of them).
    held = 2 * CLIENT_RCVBUF + CLIENT_READ_CHUNK + NOTSENT_LOWAT + WRITE_HIGH
    in_transit = held // frame_bytes + 3  # + the frames being written, read, queued
    assert seen.stale <= in_transit, seen.stale
    print(f"stalled client: {seen.stale} stale frames after resuming (bound {in_transit})")
