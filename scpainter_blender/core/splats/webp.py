"""WebP images as SOG holds them: the container's header read without decoding (size, lossless or not), and the
decoder the process uses (set by whoever has one).

Decoding WebP needs a codec that Blender's Python does not ship; the backend has OpenCV's. So core never decodes
a WebP itself: ``core.splats.sog`` takes a ``decode_webp(data: bytes, name: str) -> ndarray`` callable, and when
none is passed it asks ``decoder()`` here, which the backend sets on import (``backend/webp.py``, registered by
``backend/__init__.py``): every backend path that reads an asset (``render``, its ``--check``, ``vary``, training)
decodes with it. In Blender none is set, and the import converts a SOG through ``python -m backend splat-asset``
as it converts meshes (``scene.gaussians``).

The header (Google's "WebP Container Specification" and "WebP Lossless Bitstream Specification"): ``RIFF`` size
``WEBP``, then one chunk: ``VP8L`` (lossless: a 0x2f signature byte, then 14 bits width - 1 and 14 bits height - 1,
little-endian), ``VP8 `` (lossy) or ``VP8X`` (extended: canvas width - 1 and height - 1 in 24 bits each, then
chunks, the image's ``VP8L`` or ``VP8 `` among them; an animation has ``ANMF`` frames instead).

Standard library only (the backend imports this at start-up, and ``doctor`` must run without numpy).
"""

from __future__ import annotations

#: The largest WebP side (14 bits): SOG textures are at most this many texels wide and high.
MAX_SIDE = 16383

_decoder = None


def set_decoder(decode) -> None:
    """Make ``decode(data: bytes, name: str) -> (H, W, 4) uint8 RGBA ndarray`` this process's WebP decoder (it
    raises ValueError with a message when the bytes do not decode)."""
    global _decoder
    _decoder = decode


def decoder():
    """This process's WebP decoder (``set_decoder``), or None when it has none (Blender)."""
    return _decoder


def header(data: bytes):
    """(width, height, kind) of a WebP file's bytes, kind "lossless", "lossy" or "animation"; ValueError with what
    is wrong when the bytes are not a WebP file."""
    if len(data) < 30 or data[:4] != b"RIFF" or data[8:12] != b"WEBP":
        raise ValueError("not a WebP image (no RIFF/WEBP header)")
    chunk = data[12:16]
    if chunk == b"VP8L":
        return (*_vp8l_size(data, 20), "lossless")
    if chunk == b"VP8 ":
        return (int.from_bytes(data[26:28], "little") & 0x3FFF, int.from_bytes(data[28:30], "little") & 0x3FFF,
                "lossy")
    if chunk == b"VP8X":
        width = int.from_bytes(data[24:27], "little") + 1
        height = int.from_bytes(data[27:30], "little") + 1
        pos = 30
        while pos + 8 <= len(data):  # the chunks after VP8X: the image's bitstream tells its kind
            tag, size = data[pos:pos + 4], int.from_bytes(data[pos + 4:pos + 8], "little")
            if tag == b"VP8L":
                return width, height, "lossless"
            if tag in (b"VP8 ", b"ALPH"):
                return width, height, "lossy"
            if tag in (b"ANIM", b"ANMF"):
                return width, height, "animation"
            pos += 8 + size + (size & 1)  # chunks are padded to an even size
        raise ValueError("an extended WebP without an image chunk (VP8L or VP8)")
    raise ValueError(f"unknown WebP chunk {chunk!r}")


def _vp8l_size(data: bytes, at: int):
    if data[at] != 0x2F:
        raise ValueError("a lossless WebP without its 0x2f signature byte")
    bits = int.from_bytes(data[at + 1:at + 5], "little")
    return (bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1
