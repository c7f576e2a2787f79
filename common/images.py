"""An image's pixel size from its header, read before anything decodes it.

A camera frame's bytes are capped on the wire, its pixels are not: a 420 KB PNG
can unpack to gigabytes. Every decoder of a frame from outside (the viewer's
video, a replay's recorded frames, the recorder that keeps them) asks
:func:`check_image` first: a PNG or JPEG whose header names no more than
MAX_PIXELS, and the size the frame claims; anything else is refused unread.
"""

from __future__ import annotations

import struct

MAX_PIXELS = 4096 * 2048
"""A floor view is 2 mm a pixel: 8 m by 4 m of arena. Decoded as RGB: 24 MiB."""

_PNG = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (baseline, progressive, lossless ...); C4, C8, CC are not.
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


class ImageRefused(ValueError):
    """An image that must not be decoded, and why, in words."""


def image_size(data: bytes) -> tuple[str, int, int]:
    """(format, width, height) from a PNG's or JPEG's header; ImageRefused otherwise."""
    if data.startswith(_PNG):
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise ImageRefused("a PNG without its IHDR header")
        width, height = struct.unpack(">II", data[16:24])
        return "png", width, height
    if data.startswith(b"\xff\xd8"):
        return ("jpeg", *_jpeg_size(data))
    raise ImageRefused("neither a PNG nor a JPEG")


def _jpeg_size(data: bytes) -> tuple[int, int]:
    at = 2
    while at + 4 <= len(data):
        if data[at] != 0xFF:
            raise ImageRefused("a JPEG whose markers do not follow each other")
        marker = data[at + 1]
        if marker == 0xFF:  # fill byte
            at += 1
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length
            at += 2
            continue
        (length,) = struct.unpack(">H", data[at + 2 : at + 4])
        if marker in _SOF:
            if at + 9 > len(data):
                break
            height, width = struct.unpack(">HH", data[at + 5 : at + 9])
            return width, height
        if marker == 0xDA or length < 2:  # image data before any frame header
            break
        at += 2 + length
    raise ImageRefused("a JPEG without a frame header")


def check_image(
    data: bytes, *, claimed: tuple[int, int] | None = None, max_pixels: int = MAX_PIXELS
) -> tuple[int, int]:
    """(width, height) of an image that may be decoded; ImageRefused in words otherwise."""
    _, width, height = image_size(data)
    if width <= 0 or height <= 0:
        raise ImageRefused(f"an image of {width}×{height} pixels")
    if width * height > max_pixels:
        raise ImageRefused(
            f"an image of {width}×{height} pixels: more than the {max_pixels:,} allowed"
        )
    if claimed is not None and (width, height) != claimed:
        raise ImageRefused(
            f"an image of {width}×{height} pixels in a frame that says {claimed[0]}×{claimed[1]}"
        )
    return width, height
