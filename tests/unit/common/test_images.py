"""An image's size from its header, before any decoder sees it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from common.images import ImageRefused, check_image, image_size


def test_the_size_is_read_from_a_png_or_jpeg_header_and_anything_else_is_refused() -> None:
    picture = np.zeros((48, 64, 3), np.uint8)
    for ext, kind in ((".png", "png"), (".jpg", "jpeg")):
        ok, data = cv2.imencode(ext, picture)
        assert ok
        assert image_size(data.tobytes()) == (kind, 64, 48)
        assert check_image(data.tobytes(), claimed=(64, 48)) == (64, 48)
        with pytest.raises(ImageRefused, match="says 640×480"):
            check_image(data.tobytes(), claimed=(640, 480))
        with pytest.raises(ImageRefused, match="more than the 1,000 allowed"):
            check_image(data.tobytes(), max_pixels=1000)
    ok, tiff = cv2.imencode(".tiff", picture)  # OpenCV would decode it: never asked to
    with pytest.raises(ImageRefused, match="neither a PNG nor a JPEG"):
        check_image(tiff.tobytes())
    for broken in (b"\x89PNG\r\n\x1a\n" + b"\x00" * 4, b"\xff\xd8\xff\xda\x00\x02", b"\xff\xd8"):
        with pytest.raises(ImageRefused):
            check_image(broken)
