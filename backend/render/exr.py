"""OpenEXR files for the condition layers: float32 channels, single part, scanline, uncompressed.

Written by hand from the OpenEXR file layout (magic, version 2, header attributes ``channels compression
dataWindow displayWindow lineOrder pixelAspectRatio screenWindowCenter screenWindowWidth``, a table of scanline
offsets, then one block per scanline with the channels in name order), so the backend needs no compiled EXR
library; every OpenEXR reader (Blender, OpenImageIO, Nuke) opens the result. Written atomically.
``read`` reads back the files ``write`` makes (uncompressed FLOAT scanline files), for resuming and tests.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from scpainter_blender.core import files, outputs

MAGIC = 20000630
FLOAT = 2


def _attr(name: str, kind: str, value: bytes) -> bytes:
    return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value


def write(path, channels: dict) -> None:
    """Write ``channels`` {name: (H, W) array} as float32. Names are sorted as OpenEXR requires."""
    names = sorted(channels)
    if not names:
        raise ValueError("an EXR needs at least one channel")
    arrays = [np.ascontiguousarray(channels[n], dtype="<f4") for n in names]
    H, W = arrays[0].shape
    if any(a.shape != (H, W) for a in arrays):
        raise ValueError("all channels must have the same (H, W) shape")
    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", FLOAT, 0, 1, 1) for n in names) + b"\0"
    box = struct.pack("<iiii", 0, 0, W - 1, H - 1)
    header = b"".join([
        struct.pack("<ii", MAGIC, 2),
        _attr("channels", "chlist", chlist),
        _attr("compression", "compression", b"\0"),
        _attr("dataWindow", "box2i", box),
        _attr("displayWindow", "box2i", box),
        _attr("lineOrder", "lineOrder", b"\0"),
        _attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
        _attr("screenWindowCenter", "v2f", struct.pack("<ff", 0.0, 0.0)),
        _attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        b"\0",
    ])
    row_bytes = 4 * W * len(names)
    block = 8 + row_bytes
    first = len(header) + 8 * H
    offsets = np.arange(H, dtype="<u8") * block + first
    # (H, channels, W): each scanline holds every channel's row in name order
    rows = np.stack(arrays, axis=1)
    lead = np.empty((H, 2), dtype="<i4")
    lead[:, 0], lead[:, 1] = np.arange(H), row_bytes
    body = np.concatenate([lead.view(np.uint8).reshape(H, 8), rows.view(np.uint8).reshape(H, row_bytes)], axis=1)
    path = os.fspath(path)
    with outputs.atomic_write(path) as f:
        f.write(header)
        f.write(offsets.tobytes())
        f.write(body.tobytes())


class ExrError(files.InputError):
    """An EXR ``read`` cannot read (not OpenEXR, compressed, not FLOAT, truncated, a damaged header): the file
    and what is wrong."""


def read(path) -> dict:
    """Channels {name: (H, W) float32} of an uncompressed FLOAT scanline EXR (as ``write`` makes them).

    ExrError naming the file for anything else: another kind of EXR, a damaged header or a truncated file (the
    sizes the header promises are checked against the file's before anything is allocated)."""
    path = os.fspath(path)
    with files.open_regular(path, ExrError) as f:
        data = f.read()
    hint = "render the conditions again: python -m backend render JOB --force"
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != MAGIC:
        raise ExrError(path, "(file)", "not an OpenEXR file", hint=hint)
    try:
        pos, attrs = 8, {}
        while True:
            end = data.index(b"\0", pos)
            name = data[pos:end].decode()
            pos = end + 1
            if not name:
                break
            end = data.index(b"\0", pos)
            kind = data[pos:end].decode()
            (size,) = struct.unpack_from("<i", data, end + 1)
            if size < 0 or end + 5 + size > len(data):
                raise ExrError(path, name, f"attribute size {size} runs past the end of the file", hint=hint)
            attrs[name] = (kind, data[end + 5:end + 5 + size])
            pos = end + 5 + size
        for name in ("channels", "compression", "dataWindow"):
            if name not in attrs:
                raise ExrError(path, name, "missing from the header", hint=hint)
        if attrs["compression"][1] != b"\0":
            raise ExrError(path, "compression", "only uncompressed EXR files are read here", hint=hint)
        x0, y0, x1, y1 = struct.unpack("<iiii", attrs["dataWindow"][1])
        W, H = x1 - x0 + 1, y1 - y0 + 1
        chl, names, p = attrs["channels"][1], [], 0
        while chl[p:p + 1] != b"\0":
            end = chl.index(b"\0", p)
            names.append(chl[p:end].decode())
            if struct.unpack_from("<i", chl, end + 1)[0] != FLOAT:
                raise ExrError(path, "channels", f"channel {names[-1]!r} is not FLOAT", hint=hint)
            p = end + 17
    except (ValueError, struct.error, UnicodeDecodeError) as e:  # (ExrError is a ValueError: passed on as is)
        if isinstance(e, ExrError):
            raise
        raise ExrError(path, "(file)", f"the header is damaged ({e})", hint=hint) from None
    row = 8 + 4 * len(names) * W  # each scanline block: y, byte count, then the channels
    if W < 1 or H < 1 or not names or len(data) < pos + H * (8 + row):
        raise ExrError(path, "dataWindow", f"{W}x{H} pixels of {len(names)} channels do not fit in the file's "
                                           f"{len(data)} bytes (truncated or damaged)", hint=hint)
    offsets = np.frombuffer(data, dtype="<u8", count=H, offset=pos)
    if np.any(offsets > len(data) - row):
        raise ExrError(path, "(offsets)", "a scanline offset points past the end of the file", hint=hint)
    out = np.empty((H, len(names), W), np.float32)
    for y, off in enumerate(offsets):
        out[y] = np.frombuffer(data, dtype="<f4", count=len(names) * W, offset=int(off) + 8).reshape(len(names), W)
    return {n: out[:, i, :].copy() for i, n in enumerate(names)}
