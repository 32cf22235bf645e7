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
SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def eight_bit(rgb: np.ndarray) -> np.ndarray:
    """``rgb`` as ``write_png`` writes it: float in [0, 1] rounded to uint8 (clipped first); uint8 as it is."""
    return rgb if rgb.dtype == np.uint8 else (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def write_png(path, rgb, text: dict | None = None) -> None:
    """8-bit RGB PNG (the condition image is display-referred already), written atomically. rgb:
    (H, W, 3) float in [0, 1] (rounded to 8 bits) or uint8 (written as it is); (H, W): an 8-bit greyscale PNG (a
    nuScenes map). ``text``: Latin-1 keyword -> value pairs written as ``tEXt`` chunks before the pixels
    (``has_text`` reads them back)."""
    a = eight_bit(rgb)
    H, W = a.shape[:2]
    channels = 1 if a.ndim == 2 else 3
    raw = np.concatenate([np.zeros((H, 1), np.uint8), a.reshape(H, W * channels)], axis=1).tobytes()
    texts = b"".join(_chunk(b"tEXt", k.encode("latin-1") + b"\0" + v.encode("latin-1"))
                     for k, v in (text or {}).items())
    colour = 0 if channels == 1 else 2
    png = (SIGNATURE + _chunk(b"IHDR", struct.pack(">IIBBBBB", W, H, 8, colour, 0, 0, 0)) + texts
           + _chunk(b"IDAT", zlib.compress(raw, LEVEL)) + _chunk(b"IEND", b""))
    with outputs.atomic_write(path) as f:
        f.write(png)


def has_text(path, keyword: str, value: str) -> bool:
    """Whether the file at ``path`` is a PNG with the ``tEXt`` chunk ``keyword`` = ``value`` before its pixels
    (as ``write_png(..., text=)`` writes it): how a command knows a file at its destination is one it wrote. Reads
    the chunks before the first ``IDAT`` only (at most 64 KB); a missing or unreadable file, or any other content,
    is False."""
    from scpainter_blender.core import files
    from scpainter_blender.core.errors import InputError

    try:
        with files.open_regular(path) as f:
            head = f.read(1 << 16)
    except (InputError, OSError):
        return False
    if not head.startswith(SIGNATURE):
        return False
    want, at = keyword.encode("latin-1") + b"\0" + value.encode("latin-1"), len(SIGNATURE)
    while at + 8 <= len(head):
        n, kind = struct.unpack(">I4s", head[at:at + 8])
        if kind == b"IDAT":
            return False
        if kind == b"tEXt" and head[at + 8:at + 8 + n] == want:
            return True
        at += 12 + n
    return False
