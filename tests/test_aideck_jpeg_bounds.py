"""The AI-deck stream never decodes a JPEG bigger than its header says (a decompression bomb:
a few hundred bytes declaring 30000 x 30000 pixels)."""

from __future__ import annotations

import cv2
import numpy as np

from drivers.crazyflie.aideck_stream import decode_image, jpeg_size
from drivers.crazyflie.cpx import AssembledImage, ImageHeader


def _jpeg(w: int, h: int) -> bytes:
    img = (np.arange(w * h, dtype=np.uint32) % 251).astype(np.uint8).reshape(h, w)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    return buf.tobytes()


def _declare(data: bytes, w: int, h: int) -> bytes:
    """The same JPEG with its start-of-frame segment saying ``w`` x ``h``."""
    i = data.index(b"\xff\xc0")
    out = bytearray(data)
    out[i + 5 : i + 9] = bytes([h >> 8, h & 255, w >> 8, w & 255])
    return bytes(out)


def _frame(payload: bytes, w: int = 324, h: int = 244) -> AssembledImage:
    return AssembledImage(ImageHeader(w, h, 1, 1, len(payload)), payload, 0.0, 0.0, 1)


def test_jpeg_size_reads_the_frame_header() -> None:
    assert jpeg_size(_jpeg(324, 244)) == (324, 244)
    assert jpeg_size(_declare(_jpeg(16, 8), 30000, 30000)) == (30000, 30000)
    assert jpeg_size(b"\xff\xd8" + b"\x00" * 100_000) is None  # no markers: no size
    assert jpeg_size(b"\xff\xd8\xff\xe0\x00") is None  # truncated segment


def test_a_frame_is_decoded_only_at_the_size_its_header_announced() -> None:
    good = decode_image(_frame(_jpeg(324, 244)))
    assert good is not None and good.shape[:2] == (244, 324)
    bomb = _declare(_jpeg(16, 8), 30000, 30000)
    assert decode_image(_frame(bomb)) is None  # refused before cv2.imdecode
    assert decode_image(_frame(_jpeg(320, 240))) is None  # disagrees with the header
