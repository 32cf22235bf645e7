"""GaussianSplats3D's ``.ksplat`` (mkkellogg/GaussianSplats3D ``src/loaders/SplatBuffer.js``), compression levels
0, 1 and 2, read as the raw INRIA values of ``core.splats.gaussians.GaussianPly`` (``format`` = "ksplat"),
the way playcanvas/splat-transform reads it (``src/lib/readers/read-ksplat.ts``). Some such files were once
saved as ``.splat``: ``core.splats.reader`` tells them apart by the header (``looks_like_ksplat``).

Layout, little-endian:

* Main header, 4096 bytes: version major uint8 (0) and minor uint8 (>= 1) at 0, uint32 at 4 the number of
  section headers, at 8 the sections used, at 12 the most Gaussians, at 16 the Gaussians stored (N), uint16 at 20
  the compression level (0-2), float32 at 24 the scene centre, at 36 / 40 the SH range of level 2 (0 means -1.5 /
  1.5, as the readers take it).
* Section headers, 1024 bytes each: uint32 at 0 Gaussians in it, at 4 the slots it holds (its data has room for
  that many), at 8 the bucket capacity, at 12 the bucket count, float32 at 16 the bucket block size, uint16 at 20
  the bytes per bucket (its centre, 3 float32), uint32 at 24 the quantisation range Q (0: 1 at level 0, 32767
  otherwise), at 32 the full buckets, at 36 the partial ones, uint16 at 40 the SH degree (0-2 written; 3 read).
* Each section's data, after all section headers: the partial buckets' sizes (uint32 each), the bucket centres
  (bytes per bucket × buckets), then one record per slot: position, scale, rotation (w x y z), colour RGBA bytes,
  SH. Level 0: float32 position, σ and rotation, float32 SH. Levels 1 and 2: uint16 positions, p = (k - Q) ·
  (block size / 2 / Q) + the bucket's centre (the first full-bucket-count × capacity Gaussians fill full buckets
  in order, the rest the partial ones by their sizes), half-float σ and rotation, SH half floats (1) or bytes
  mapped linearly to the SH range (2).
* Values: σ is linear (read as log σ; σ <= 0 as -10, as splat-transform does), f_dc = (byte / 255 - 0.5) / SH_C0,
  opacity the logit of alpha byte / 255 clamped to [1e-6, 1 - 1e-6]. SH are stored band by band, each band
  channel-major (band 1: r1 r2 r3 g1 g2 g3 b1 b2 b3; band 2: five per channel ...), and regrouped to INRIA's
  channel-major ``f_rest``.

Axes: PLY-style, like an INRIA PLY (splat-transform's Transform.PLY); the values are taken as stored.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os

import numpy as np

from .gaussians import GaussianPly, SplatsError, read_bytes
from .sh import SH_C0

MAIN_HEADER = 4096
SECTION_HEADER = 1024
LEVELS = (0, 1, 2)
#: The default quantisation range of levels 1 and 2 (SplatBuffer's CompressionLevels' ScaleRange).
DEFAULT_RANGE = 32767
#: SH range of level 2 when the header holds 0 (SplatBuffer's defaults).
DEFAULT_SH_RANGE = (-1.5, 1.5)
_SH_COUNT = (0, 9, 24, 45)
_ALPHA_EPS = 1e-6
#: log σ for a stored σ <= 0 (splat-transform's reader).
_LOG_SCALE_FLOOR = -10.0
#: Section headers a file may claim: each costs 1024 bytes of header, so a real file has few (GaussianSplats3D
#: writes one per 1 M Gaussians or so); more is a damaged or foreign file.
MAX_SECTIONS = 65536

_MAIN = np.dtype([("major", "u1"), ("minor", "u1"), ("pad", "<u2"), ("max_sections", "<u4"), ("sections", "<u4"),
                  ("max_splats", "<u4"), ("splats", "<u4"), ("level", "<u2"), ("pad2", "<u2"),
                  ("center", "<f4", 3), ("sh_min", "<f4"), ("sh_max", "<f4")])
_SECTION = np.dtype([("splats", "<u4"), ("max_splats", "<u4"), ("bucket_capacity", "<u4"), ("buckets", "<u4"),
                     ("block_size", "<f4"), ("bucket_bytes", "<u2"), ("pad", "<u2"), ("range", "<u4"),
                     ("storage", "<u4"), ("full_buckets", "<u4"), ("partial_buckets", "<u4"), ("sh_degree", "<u2")])


def record_dtype(level: int, degree: int) -> np.dtype:
    """One Gaussian's record at compression ``level`` with SH ``degree`` (module docstring)."""
    f = "<f4" if level == 0 else "<f2"
    fields = [("xyz", "<f4" if level == 0 else "<u2", (3,)), ("scale", f, (3,)), ("rot", f, (4,)),
              ("rgba", "u1", (4,))]
    if degree:
        fields.append(("sh", ("<f4", "<f2", "u1")[level], (_SH_COUNT[degree],)))
    return np.dtype(fields)


def _sections(head: bytes, count: int) -> np.ndarray:
    """The ``count`` section headers (one ``_SECTION`` at the start of each 1024-byte slot)."""
    return np.ndarray((count,), _SECTION, head, MAIN_HEADER, (SECTION_HEADER,)) if count else np.zeros(0, _SECTION)


def _layout(main, sections) -> list:
    """Per section (offset of its data from the first section's data, its bucket block bytes, record dtype,
    its data bytes in all)."""
    out, at = [], 0
    for s in sections:
        degree = int(s["sh_degree"])
        rec = record_dtype(int(main["level"]), min(degree, 3))
        bucket_bytes = int(s["bucket_bytes"]) * int(s["buckets"]) + 4 * int(s["partial_buckets"])
        size = bucket_bytes + rec.itemsize * int(s["max_splats"])
        out.append((at, bucket_bytes, rec, size))
        at += size
    return out


def header_problem(head: bytes, size: int) -> str | None:
    """Why the first bytes ``head`` of a file of ``size`` bytes are no ``.ksplat``'s header (its main header and
    section headers consistent with each other and the size), or None when they are one. ``head`` should hold the
    main header and all section headers (``MAIN_HEADER + max_sections · SECTION_HEADER`` bytes)."""
    if len(head) < MAIN_HEADER or size < MAIN_HEADER:
        return f"shorter than the {MAIN_HEADER}-byte main header"
    main = np.frombuffer(head, _MAIN, 1)[0]
    if main["major"] != 0 or main["minor"] < 1 or main["pad"] != 0:
        return f"version bytes {int(main['major'])}.{int(main['minor'])} (0.1 or later expected)"
    if int(main["level"]) not in LEVELS:
        return f"compression level {int(main['level'])} (0, 1 or 2 expected)"
    n_sec = int(main["max_sections"])
    if not 1 <= n_sec <= MAX_SECTIONS or int(main["sections"]) > n_sec:
        return f"{n_sec} section headers ({int(main['sections'])} used)"
    if len(head) < MAIN_HEADER + n_sec * SECTION_HEADER:
        return f"{n_sec} section headers, more than the file's {size:,} bytes hold"
    sections = _sections(head, n_sec)
    if int(sections["splats"].astype(np.int64).sum()) != int(main["splats"]):
        return (f"the sections hold {int(sections['splats'].astype(np.int64).sum()):,} Gaussians, the main header "
                f"says {int(main['splats']):,}")
    if np.any(sections["splats"] > sections["max_splats"]) or np.any(sections["sh_degree"] > 3):
        return "a section with more Gaussians than slots, or an SH degree above 3"
    layout = _layout(main, sections)
    end = MAIN_HEADER + n_sec * SECTION_HEADER + (layout[-1][0] + layout[-1][3] if layout else 0)
    if end > size:
        return f"its sections need {end:,} bytes, the file has {size:,}"
    return None


def looks_like_ksplat(head: bytes, size: int) -> bool:
    """True when ``head`` (main header and section headers) is a consistent ``.ksplat`` header (``header_problem``)."""
    return header_problem(head, size) is None


def read(path) -> GaussianPly:
    """Read a ``.ksplat`` (module docstring) as raw INRIA values; SplatsError naming the file if unusable."""
    path = os.fspath(path)
    data = read_bytes(path)
    problem = header_problem(data, len(data))
    if problem:
        raise SplatsError(path, f"not a GaussianSplats3D .ksplat file: {problem}", "header")
    main = np.frombuffer(data, _MAIN, 1)[0]
    level = int(main["level"])
    sections = _sections(data, int(main["max_sections"]))
    degree = int(sections["sh_degree"][sections["splats"] > 0].max(initial=0))
    n = int(main["splats"])
    sh_lo = float(main["sh_min"]) or DEFAULT_SH_RANGE[0]
    sh_hi = float(main["sh_max"]) or DEFAULT_SH_RANGE[1]
    xyz, scale, rot = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 4))
    rgba, f_rest = np.empty((n, 4), np.uint8), np.zeros((n, 3, _SH_COUNT[degree] // 3), np.float32)
    data_start, at = MAIN_HEADER + len(sections) * SECTION_HEADER, 0
    for s, (offset, bucket_bytes, rec, _size) in zip(sections, _layout(main, sections)):
        m = int(s["splats"])
        if not m:
            continue
        base = data_start + offset
        r = np.frombuffer(data, rec, m, base + bucket_bytes)
        if level == 0:
            xyz[at:at + m] = r["xyz"]
        else:
            xyz[at:at + m] = _dequantise(path, data, base, s, r["xyz"], m)
        scale[at:at + m], rot[at:at + m], rgba[at:at + m] = r["scale"], r["rot"], r["rgba"]
        sec_degree = int(s["sh_degree"])
        if sec_degree:
            sh = r["sh"].astype(np.float64)
            if level == 2:
                sh = sh_lo + sh / 255.0 * (sh_hi - sh_lo)
            f_rest[at:at + m] = _channel_major(sh, sec_degree, degree)
        at += m
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scale = np.where(scale > 0, np.log(np.where(scale > 0, scale, 1.0)), _LOG_SCALE_FLOOR)
    a = np.clip(rgba[:, 3].astype(np.float64) / 255.0, _ALPHA_EPS, 1.0 - _ALPHA_EPS)
    return GaussianPly(xyz=xyz.astype(np.float32), f_dc=((rgba[:, :3] / 255.0 - 0.5) / SH_C0).astype(np.float32),
                       f_rest=f_rest, opacity=np.log(a / (1.0 - a)).astype(np.float32),
                       scale=log_scale.astype(np.float32), rot=rot.astype(np.float32), format="ksplat")


def _dequantise(path, data, base, s, k, m) -> np.ndarray:
    """Positions of a level 1/2 section from its uint16 words and bucket centres."""
    q = int(s["range"]) or DEFAULT_RANGE
    cap, full, partial = int(s["bucket_capacity"]), int(s["full_buckets"]), int(s["partial_buckets"])
    buckets = int(s["buckets"])
    if int(s["bucket_bytes"]) < 12 or full + partial > buckets or (full and not cap) or full * cap > m:
        raise SplatsError(path, f"a section's buckets are inconsistent ({full} full of {cap}, {partial} partial, "
                                f"{buckets} in all, {int(s['bucket_bytes'])} bytes each)", "section")
    sizes = np.frombuffer(data, "<u4", partial, base).astype(np.int64)
    centres = np.ndarray((buckets, 3), "<f4", data, base + 4 * partial, (int(s["bucket_bytes"]), 4))
    i = np.arange(m)
    bucket = i // max(cap, 1)
    rest = i >= full * cap
    if rest.any():
        ends = np.cumsum(sizes)
        if int(ends[-1] if len(ends) else 0) < m - full * cap:
            raise SplatsError(path, f"a section's partial buckets hold {int(ends[-1]) if len(ends) else 0:,} "
                                    f"Gaussians, {m - full * cap:,} are left after its full buckets", "section")
        bucket[rest] = full + np.searchsorted(ends, i[rest] - full * cap, side="right")
    step = float(s["block_size"]) / 2.0 / q
    return (k.astype(np.float64) - q) * step + centres[bucket].astype(np.float64)


def _channel_major(sh, sec_degree: int, degree: int) -> np.ndarray:
    """(m, 3, (degree + 1)² - 1) channel-major f_rest of band-by-band, channel-major-per-band stored SH."""
    out = np.zeros((len(sh), 3, (degree + 1) ** 2 - 1), np.float32)
    at, coeff = 0, 0
    for band in range(1, sec_degree + 1):
        width = 2 * band + 1
        out[:, :, coeff:coeff + width] = sh[:, at:at + 3 * width].reshape(-1, 3, width)
        at, coeff = at + 3 * width, coeff + width
    return out
