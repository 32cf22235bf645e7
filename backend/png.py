"""PNG files the backend writes: the condition image's preview (``render``) and the generated frames
(``generate``). stdlib only (zlib, struct), so no image library is needed to write them."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from scpainter_blender.core import outputs

#: zlib's level for the pixel data. 1, not zlib's default 6: 2-4x faster (a 576 x 1024 preview ~13-27 ms against
#: ~40-75 ms, a large part of a rendered frame's cost) for files within 5 % of the size, and the same pixels
#: (bench/render_writes.py). zlib releases the GIL while it compresses, so a writer thread overlaps it.
LEVEL = 1


def write_png(path, rgb) -> None:
    """8-bit RGB PNG (the condition image is display-referred already), written atomically. rgb:
    (H, W, 3) float in [0, 1] (rounded to 8 bits) or uint8 (written as it is)."""
    a = rgb if rgb.dtype == np.uint8 else (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    H, W, _ = a.shape
    raw = np.concatenate([np.zeros((H, 1), np.uint8), a.reshape(H, W * 3)], axis=1).tobytes()

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, 2, 0, 0, 0))
           + chunk(b"IDAT", zlib.compress(raw, LEVEL)) + chunk(b"IEND", b""))
    with outputs.atomic_write(path) as f:
        f.write(png)
