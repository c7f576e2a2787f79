"""A camera frame that is a decompression bomb, through a real router to the viewer's
camera feed: its header is read, its pixels never decoded; an honest frame still is."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np

from common import keys
from common.messages import CameraFrame, encode
from common.service import close_session, open_session
from tests.conftest import Router, wait_for
from viewers.web.arena_video import CameraFeed


def _png_bomb(width: int, height: int) -> bytes:
    """A grey PNG of zeros: a few KB that unpack to width × height bytes and more."""
    pack = zlib.compressobj(9)
    row = bytes(width + 1)  # filter byte 0, then the pixels
    body = b"".join(pack.compress(row) for _ in range(height)) + pack.flush()

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data)
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", body) + chunk(b"IEND", b"")
    )


def _frame(seq: int, data: bytes, width: int, height: int) -> bytes:
    frame = CameraFrame(
        world="arena", camera="cam", seq=seq, captured_at=0.0, width=width, height=height, data=data
    )
    return encode(frame)


def test_a_bomb_of_a_frame_is_refused_from_its_header_and_a_real_one_still_shows(
    router: Router,
) -> None:
    session = open_session(router.options(), wait=10.0)
    feed = CameraFeed(session, router.realm, "arena")
    try:
        key = keys.camera_floor(router.realm, "arena", "cam")
        bomb = _png_bomb(6000, 4000)  # 24 M pixels: 72 MB once decoded as a colour image
        assert len(bomb) < 100_000
        session.put(key, _frame(1, bomb, 1024, 768))  # it says 1024×768
        wait_for(lambda: feed.floor() is None and feed.refused == 1, 10, "the bomb refused")
        honest = _png_bomb(4096, 4096)  # says its true size, but more than the cap
        session.put(key, _frame(2, honest, 4096, 4096))
        wait_for(lambda: feed.floor() is None and feed.refused == 2, 10, "the big one refused")
        assert feed.frames == 0  # nothing was decoded
        ok, jpeg = cv2.imencode(".jpg", np.full((480, 640, 3), 90, np.uint8))
        assert ok
        session.put(key, _frame(3, jpeg.tobytes(), 640, 480))
        shown = wait_for(lambda: feed.floor(), 10, "the real frame decoded")
        assert shown[1].shape == (480, 640, 3)  # type: ignore[index]
        assert feed.frames == 1
    finally:
        feed.close()
        close_session(session)
