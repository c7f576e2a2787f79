"""Small video files for the camera's tests: frames of known shades, some wiped if asked."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def write_video(
    path: Path,
    frames: int,
    fps: float,
    corrupt: range = range(0),
    size: tuple[int, int] = (160, 120),
) -> Path:
    """An MJPG AVI whose frame i is grey ``(4 i) % 250``; the frames in ``corrupt`` have their
    JPEG data zeroed (the container intact), so they do not decode."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, size)
    for i in range(frames):
        writer.write(np.full((size[1], size[0], 3), (i * 4) % 250, np.uint8))
    writer.release()
    if corrupt:
        data = bytearray(path.read_bytes())
        chunks, at = [], data.find(b"00dc")
        while at >= 0:
            length = int.from_bytes(data[at + 4 : at + 8], "little")
            if data[at + 8 : at + 10] == b"\xff\xd8":  # a JPEG frame's chunk
                chunks.append((at + 8, length))
            at = data.find(b"00dc", at + 8)
        for start, length in (chunks[i] for i in corrupt):
            data[start : start + length] = bytes(length)
        path.write_bytes(bytes(data))
    return path
