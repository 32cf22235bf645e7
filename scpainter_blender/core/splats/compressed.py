"""The two compact Gaussian formats of web viewers, both quantised: SuperSplat's compressed PLY (read) and
antimatter15's ``.splat`` (read and write), as the raw INRIA values of ``core.splats.gaussians.GaussianPly``.

SuperSplat compressed PLY ("supersplat_compressed"; writers: playcanvas/supersplat ``src/splat-serialize.ts``
``serializePlyCompressed``, playcanvas/splat-transform ``src/lib/writers/write-compressed-ply.ts`` and
``compressed-chunk.ts``; readers: playcanvas/engine ``src/scene/gsplat/gsplat-compressed-data.js``,
playcanvas/splat-transform ``src/lib/readers/decompress-ply.ts``). Elements, in order:

* ``chunk`` (one per 256 consecutive vertices, ceil(M / 256) rows), float: ``min_x min_y min_z max_x max_y max_z``
  (the box of the chunk's means), ``min_scale_x.. max_scale_z`` (range of the log scales, clamped to [-20, 20]),
  and in newer files ``min_r min_g min_b max_r max_g max_b`` (range of the colours 0.5 + C0 f_dc).
* ``vertex`` (M rows), uint32 ``packed_position packed_rotation packed_scale packed_color``.
* optional ``sh`` (M rows), uchar ``f_rest_0..`` (9, 24 or 45, INRIA's channel-major order).

A u-bit field k decodes to t = k / (2^u - 1) and a value lo + t (hi - lo) with the chunk's range.
``packed_position`` and ``packed_scale``: x in bits 21-31 (11 bits), y in bits 11-20 (10), z in bits 0-10 (11).
``packed_color``: r bits 24-31, g 16-23, b 8-15, alpha 0-7 (8 each); with chunk colours r = lerp(min_r, max_r, t),
without them r = t; f_dc = (r - 0.5) / C0; alpha is the sigmoid of the opacity itself, stored as the logit
log(a / (1 - a)), with ±40 for a = 0 / 1 as the engine does. ``packed_rotation`` ("smallest three"): bits 30-31
= index i of the largest-magnitude component in file order (rot_0..rot_3 = w, x, y, z); the other three
components, in increasing index order, are in bits 20-29, 10-19 and 0-9 as (k / 1023 - 0.5) · √2 (the writer
stores q_j · √2/2 + 0.5, so ±1/√2 spans the range); the writer flips the quaternion's sign so component i is
positive, and it is decoded as sqrt(max(0, 1 - a² - b² - c²)). ``sh`` bytes: the writer stores
trunc((v / 8 + 0.5) · 256) clamped to 0..255; decoded to the bucket's middle ((k + 0.5) / 256 - 0.5) · 8, with
0 → -4 and 255 → +4 (splat-transform's reader; the engine's k · 8/255 - 4 differs by < 1/64).

antimatter15 ``.splat`` ("splat"; antimatter15/splat ``convert.py`` writes it, ``main.js`` reads it): no header,
32 bytes per Gaussian, little-endian: position 3 × float32, scale 3 × float32 (σ itself, not its log), colour
RGBA 4 × uint8 (r = (0.5 + C0 f_dc) · 255, alpha = sigmoid(opacity) · 255), quaternion 4 × uint8 (w, x, y, z),
byte = q / |q| · 128 + 128, read back as (byte - 128) / 128. Read as log σ, f_dc = (byte / 255 - 0.5) / C0,
opacity logit of byte / 255 clamped to [1e-6, 1 - 1e-6] (so 0 and 255 stay finite), and that raw quaternion.
No SH beyond degree 0.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np

from .. import outputs
from . import ply_format
from .sh import SH_C0
from .gaussians import (DROPPED_REASONS, MOSTLY_INVALID_SHARE, GaussianPly, SplatsError, decode, open_file,
                        valid_rows)

if TYPE_CHECKING:
    from .gaussians import Gaussians

#: SuperSplat compressed PLY: splats per chunk, and the chunk/vertex properties (module docstring; the readers
#: choose this layout by the ``chunk`` element or ``packed_*`` vertex properties).
CHUNK_SIZE = 256
_CHUNK_PROPS = ("min_x", "min_y", "min_z", "max_x", "max_y", "max_z", "min_scale_x", "min_scale_y", "min_scale_z",
                "max_scale_x", "max_scale_y", "max_scale_z")
_CHUNK_COLOR_PROPS = ("min_r", "min_g", "min_b", "max_r", "max_g", "max_b")
PACKED_PROPS = ("packed_position", "packed_rotation", "packed_scale", "packed_color")
#: Opacity logit for alpha bytes 0 and 255 (playcanvas/engine gsplat-compressed-data.js uses ±40).
_COMPRESSED_LOGIT_LIMIT = 40.0

#: antimatter15 .splat: one 32-byte little-endian record per Gaussian.
SPLAT_RECORD = np.dtype([("xyz", "<f4", (3,)), ("scale", "<f4", (3,)), ("rgba", "u1", (4,)), ("rot", "u1", (4,))])
_SPLAT_ALPHA_EPS = 1e-6


# -- SuperSplat compressed PLY -------------------------------------------------------------------------------------

def _require_properties(path, what, element, types: dict, needed, allowed, expected) -> None:
    """Refuse an element of the compressed layout that lacks one of ``needed`` or stores one in another type."""
    missing = [p for p in needed if p not in types]
    if missing:
        raise SplatsError(path, f"{what} needs {element} properties {list(needed)}; missing {missing}", missing[0])
    bad = [p for p in needed if types[p] not in allowed]
    if bad:
        raise SplatsError(path, f"{what}: {element} property {bad[0]!r} is "
                                f"{ply_format.type_name(np.dtype(types[bad[0]]))}, expected {expected}", bad[0])


def check_header(elements: list, path: str | os.PathLike) -> None:
    """Refuse a compressed layout that is incomplete or inconsistent, naming what is wrong (before reading data)."""
    what = "a SuperSplat compressed PLY"
    chunk, vertex, sh = (ply_format.element(elements, n) for n in ("chunk", "vertex", "sh"))
    if chunk is None:
        raise SplatsError(path, f"the vertices have packed_* properties ({what}) but there is no 'chunk' element",
                          "chunk")
    _require_properties(path, what, "vertex", dict(vertex[1]), PACKED_PROPS, ("u4", "i4"), "uint (32-bit)")
    ctypes = dict(chunk[1])
    needed = _CHUNK_PROPS + (_CHUNK_COLOR_PROPS if any(p in ctypes for p in _CHUNK_COLOR_PROPS) else ())
    _require_properties(path, what, "chunk", ctypes, needed, ("f4", "f8"), "float")
    expect = -(-vertex[0] // CHUNK_SIZE)
    if chunk[0] != expect:
        raise SplatsError(path, f"{what}: {vertex[0]} Gaussians need {expect} chunks of {CHUNK_SIZE}, "
                                f"the header has {chunk[0]}", "chunk")
    if sh is not None:
        names = [p for p, _ in sh[1]]
        if len(names) not in (9, 24, 45) or names != [f"f_rest_{i}" for i in range(len(names))]:
            raise SplatsError(path, f"{what}: the 'sh' element must hold f_rest_0..f_rest_(9, 24 or 45 - 1), "
                                    f"it has {len(names)} properties", "sh")
        _require_properties(path, what, "sh", dict(sh[1]), names, ("u1",), "uchar")
        if sh[0] != vertex[0]:
            raise SplatsError(path, f"{what}: the 'sh' element has {sh[0]} rows for {vertex[0]} Gaussians", "sh")


def _unorm(packed: np.ndarray, shift: int, bits: int) -> np.ndarray:
    """The ``bits``-bit field at ``shift`` as k / (2^bits - 1) in [0, 1] (float64)."""
    top = (1 << bits) - 1
    return ((packed >> np.uint32(shift)) & np.uint32(top)).astype(np.float64) / top


#: For the index of the largest quaternion component, the indices of the other three in storage order.
_SMALLEST_THREE = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


def decode_packed_rotation(packed: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (rot_0..rot_3 = w, x, y, z) from SuperSplat's 2-10-10-10 "smallest three" words."""
    packed = np.asarray(packed, np.uint32)
    small = np.stack([(_unorm(packed, s, 10) - 0.5) * np.sqrt(2.0) for s in (20, 10, 0)], axis=1)
    largest = (packed >> np.uint32(30)).astype(np.intp)
    q = np.empty((len(packed), 4), np.float64)
    rows = np.arange(len(packed))[:, None]
    q[rows, _SMALLEST_THREE[largest]] = small
    q[rows[:, 0], largest] = np.sqrt(np.maximum(0.0, 1.0 - (small * small).sum(axis=1)))
    return q


def from_elements(arrays: dict, path: str | os.PathLike) -> GaussianPly:
    """The raw values of a compressed PLY's ``chunk``, ``vertex`` and optional ``sh`` elements (structured arrays
    by name, as ``ply_format.read_elements`` gives them; the header checked by ``check_header``)."""
    chunk, vert = arrays["chunk"], arrays["vertex"]
    M = len(vert)
    ci = np.arange(M) // CHUNK_SIZE

    def ch(name):
        return np.asarray(chunk[name], np.float64)[ci]

    def lerp(lo, hi, t):  # as the readers do it: lo (1 - t) + hi t
        return ch(lo) * (1.0 - t) + ch(hi) * t

    def words(name):  # int32 words are read as their bits
        w = np.asarray(vert[name])
        return w.astype("=i4").view(np.uint32) if w.dtype.kind == "i" else w.astype(np.uint32)

    pos, scl, col = words("packed_position"), words("packed_scale"), words("packed_color")
    with np.errstate(invalid="ignore", over="ignore"):  # NaN/inf chunk values make NaN rows, dropped on decoding
        xyz = np.stack([lerp("min_x", "max_x", _unorm(pos, 21, 11)), lerp("min_y", "max_y", _unorm(pos, 11, 10)),
                        lerp("min_z", "max_z", _unorm(pos, 0, 11))], axis=1)
        scale = np.stack([lerp("min_scale_x", "max_scale_x", _unorm(scl, 21, 11)),
                          lerp("min_scale_y", "max_scale_y", _unorm(scl, 11, 10)),
                          lerp("min_scale_z", "max_scale_z", _unorm(scl, 0, 11))], axis=1)
        rgb = np.stack([_unorm(col, 24, 8), _unorm(col, 16, 8), _unorm(col, 8, 8)], axis=1)
        if "min_r" in chunk.dtype.names:
            rgb = np.stack([lerp(f"min_{c}", f"max_{c}", rgb[:, i]) for i, c in enumerate("rgb")], axis=1)
        alpha = _unorm(col, 0, 8)
        inner = np.clip(alpha, 1e-300, 1 - 1e-16)
        opacity = np.where(alpha <= 0, -_COMPRESSED_LOGIT_LIMIT,
                           np.where(alpha >= 1, _COMPRESSED_LOGIT_LIMIT, np.log(inner / (1.0 - inner))))
    f_rest = np.zeros((M, 3, 0), np.float32)
    if "sh" in arrays:
        sh = arrays["sh"]
        raw = np.stack([np.asarray(sh[f"f_rest_{i}"]) for i in range(len(sh.dtype.names))], axis=1)
        vals = ((raw.astype(np.float64) + 0.5) / 256.0 - 0.5) * 8.0
        vals[raw == 0], vals[raw == 255] = -4.0, 4.0
        f_rest = vals.astype(np.float32).reshape(M, 3, -1)
    with np.errstate(invalid="ignore", over="ignore"):  # beyond float32's range becomes inf: dropped on decoding
        return GaussianPly(xyz=xyz.astype(np.float32), f_dc=((rgb - 0.5) / SH_C0).astype(np.float32),
                           f_rest=f_rest, opacity=opacity.astype(np.float32), scale=scale.astype(np.float32),
                           rot=decode_packed_rotation(words("packed_rotation")).astype(np.float32),
                           format="supersplat_compressed")


# -- antimatter15 .splat -------------------------------------------------------------------------------------------

def read_splat(path: str | os.PathLike) -> GaussianPly:
    """Read an antimatter15 ``.splat`` file (module docstring) as raw INRIA values; SplatsError if unusable."""
    path = os.fspath(path)
    try:
        with open_file(path) as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise SplatsError(path, "the .splat file is empty (0 bytes)")
            if size % SPLAT_RECORD.itemsize:
                raise SplatsError(path, f"a .splat file holds {SPLAT_RECORD.itemsize} bytes per Gaussian, but this "
                                        f"one has {size} bytes, not a multiple of {SPLAT_RECORD.itemsize} ({size % 32} "
                                        "left over): truncated, or not a .splat file")
            buf = f.read(size)
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    if len(buf) != size:  # the file changed while being read
        raise SplatsError(path, f"only {len(buf)} of its {size} bytes could be read: the file changed while being read")
    data = np.frombuffer(buf, dtype=SPLAT_RECORD)
    rgba = data["rgba"].astype(np.float64) / 255.0
    alpha = np.clip(rgba[:, 3], _SPLAT_ALPHA_EPS, 1.0 - _SPLAT_ALPHA_EPS)
    with np.errstate(divide="ignore", invalid="ignore"):  # σ <= 0 gives -inf/NaN: dropped on decoding
        log_scale = np.log(data["scale"].astype(np.float64))
    ply = GaussianPly(xyz=data["xyz"].astype(np.float32), f_dc=((rgba[:, :3] - 0.5) / SH_C0).astype(np.float32),
                      f_rest=np.zeros((len(data), 3, 0), np.float32),
                      opacity=np.log(alpha / (1.0 - alpha)).astype(np.float32), scale=log_scale.astype(np.float32),
                      rot=((data["rot"].astype(np.float64) - 128.0) / 128.0).astype(np.float32), format="splat")
    _refuse_mostly_invalid(path, ply, data, buf[:16])
    return ply


def _refuse_mostly_invalid(path, ply: GaussianPly, data, head: bytes) -> None:
    """Refuse a ``.splat`` of which more than ``MOSTLY_INVALID_SHARE`` of the records are invalid (``valid_rows``:
    NaN, zero quaternions, beyond ``ABSURD_M``): such a file is another format under this name, not Gaussians to
    draw. A minority of such records is dropped on decoding, counted by reason, as in any file."""
    keep, dropped = valid_rows(ply)
    bad = int((~keep).sum())
    if bad <= MOSTLY_INVALID_SHARE * len(ply):
        return
    if head.startswith(b"\x1f\x8b"):
        guess = "it starts like gzip data (an SPZ file?)"
    elif head.startswith(b"PK"):
        guess = "it starts like a zip (a SOG bundle?)"
    elif head[:1] == b"\x00" and head[1:2] != b"\x00":
        guess = "it starts like a GaussianSplats3D .ksplat header, but not a consistent one (damaged?)"
    else:
        guess = "another format saved under this name, or damaged data"
    why = ", ".join(f"{n:,} {DROPPED_REASONS.get(k, k)}" for k, n in dropped.items())
    raise SplatsError(path, f"{bad:,} of its {len(ply):,} 32-byte records are no valid Gaussians ({why}): more than "
                            f"{MOSTLY_INVALID_SHARE:.0%}, so this is no antimatter15 .splat: {guess}. Convert the "
                            "original to .ply (e.g. with playcanvas/splat-transform) or export it again", "(file)")


def write_splat(path: str | os.PathLike, g: Gaussians | GaussianPly) -> None:
    """Write decoded ``Gaussians`` (or a raw ``GaussianPly``, decoded first) as an antimatter15 ``.splat``, atomically.

    Bytes as antimatter15/splat ``convert.py`` makes them, except that colour, alpha and quaternion bytes are rounded
    to the nearest value instead of truncated (readers decode both the same way); SH beyond degree 0 is dropped.
    """
    if isinstance(g, GaussianPly):
        g = decode(g)
    N = len(g)
    rec = np.zeros(N, SPLAT_RECORD)
    rec["xyz"] = g.means
    rec["scale"] = g.scales
    rgba = np.concatenate([0.5 + SH_C0 * g.sh[:, 0].astype(np.float64), g.opacities.astype(np.float64)[:, None]], 1)
    rec["rgba"] = np.clip(np.rint(rgba * 255.0), 0, 255).astype(np.uint8)
    q = g.quats.astype(np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)
    rec["rot"] = np.clip(np.rint(q * 128.0 + 128.0), 0, 255).astype(np.uint8)
    with outputs.atomic_write(os.fspath(path)) as f:
        f.write(rec.tobytes())
