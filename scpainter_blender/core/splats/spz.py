"""Niantic's SPZ (``.spz``) Gaussian files, versions 2, 3 and 4, read as the raw INRIA values of
``core.splats.gaussians.GaussianPly`` (``format`` = "spz").

The layout, as nianticlabs/spz (``src/cc/load-spz.cc``) and playcanvas/splat-transform (``src/lib/readers/
read-spz.ts``; its writer runs Niantic's own packer, ``@adobe/spz``) read and write it, all little-endian:

* Header, 16 bytes: magic ``NGSP`` (uint32 0x5053474e), version uint32, N uint32, SH degree uint8 (0-3; 4 is
  refused like splat-transform does), fractional bits uint8, flags uint8 (bit 0: trained with antialiasing; bit 1,
  ``FLAG_EXTENSIONS``: extension records follow), reserved uint8. Versions 2 and 3: the whole file (header,
  attributes, then the extension records if flagged) is one gzip stream. Version 4 (what splat-transform 3.7 writes
  by default): a plain 32-byte header (byte 15: the number of streams, uint32 at 16: the offset of a table of
  contents), the extension records if flagged (bytes 32 up to the table), then per stream (uint64 compressed size,
  uint64 uncompressed size), then each attribute as its own Zstandard frame (read with the ``zstandard`` module,
  which Blender bundles; without it the file is refused saying how to write version 3 instead).
* Extension records (nianticlabs/spz ``extensions/README.md``): back to back, each uint32 type (vendor in the high
  16 bits), uint32 byte length, then that many payload bytes. Unknown types are skipped by their length, as the
  spec says readers do; ``SPZ_ADOBE_coordinate_system`` (``COORDINATE_SYSTEM_EXTENSION``) is read (below). A record
  running past its zone, a coordinate-system payload that is not one uint32 of 0-16, or more than
  ``MAX_EXTENSION_BYTES`` of records is refused as damaged (field ``extensions``).
* The attributes, one block each, in this order: positions (N × 3 signed 24-bit fixed point: value = k / 2^fb),
  alphas (N bytes: sigmoid(opacity) · 255), colours (N × 3 bytes: f_dc · 0.15 + 0.5 as byte / 255, SPZ's own colour
  scale, not SH_C0), scales (N × 3 bytes: (log σ + 10) · 16), rotations, SH (N × 3 ((d + 1)² - 1) bytes).
* Rotations: version 2 stores x y z as bytes (byte / 127.5 - 1) with w = √(1 - x² - y² - z²) ≥ 0; versions 3 and
  4 a uint32 "smallest three": bits 30-31 the index of the largest component in (x, y, z, w) order, then from bit 0
  up the other three in decreasing index order, 10 bits each: a 9-bit magnitude m (value m / 511 · √½) and a sign
  bit above it; the largest is √(1 - Σ others²) ≥ 0.
* SH bytes are coefficient-major with the colour channel innermost ((coeff 1 r g b), (coeff 2 r g b), ...), value
  (byte - 128) / 128; INRIA's ``f_rest`` is channel-major, so they are transposed.
* Opacity is read back as the logit of byte / 255 clamped to [1e-6, 1 - 1e-6] (splat-transform's reader).

Axes: a file without a coordinate-system extension carries no axis metadata (the spec's default is RUB: x right,
y up, z back). Niantic's converters turn a PLY's frame (RDF: x right, y down, z forward) into that RUB by negating
y and z; splat-transform, which reads and writes the values unchanged ("CoordinateSystem UNSPECIFIED"), does not.
Such values are read unchanged, as splat-transform does, so a PLY converted by splat-transform reads back in its own
frame (tested); a file from Niantic's own converter comes in turned 180° about x (upside down), which the import's
placement can turn back. **Convention**: whatever a file declares, the reader returns the frame a file without the
declaration holds (SPZ's default RUB), exactly what Niantic's own loader returns with ``to = RUB`` (tested against
its WebAssembly build, ``@adobe/spz``). A file whose ``SPZ_ADOBE_coordinate_system`` record declares another of the
16 systems (``COORDINATE_SYSTEMS``; value 0 means none) is turned from it by ``system_matrix``: p_RUB = M p_file,
each Gaussian's rotation by det(M)·M (a proper rotation giving the same covariance M Σ Mᵀ, scales unchanged), its
SH by M (``gltf_splats.sh_rotation``). So one car written with and without a declaration reads back the same
(tested), where it came back turned 90°. M is the library's (nianticlabs/spz ``coordinateConverter``, packing and
unpacking alike): for the eight "standard" systems the letters' flips (R/L x, U/D y, B/F z); for the eight
"rotated" ones a quarter turn about x, (x, y, z) -> (x, z, -y), after the flips of the standard system eight
values before. That is the letters' meaning for twelve systems; for LFD, RFD, LBU and RBU the library's y and z
flips are the other way round (its files of those store y and z negated against their names), and the reader
follows the library, whose files these are.

No bpy, no torch: numpy (and zlib; ``zstandard`` for version 4 only).
"""

from __future__ import annotations

import os
import zlib

import numpy as np

from ..geometry import cameras
from .gaussians import GaussianPly, SplatsError, read_bytes
from .gltf_splats import sh_rotation

#: 'NGSP' as the little-endian uint32 every SPZ header starts with.
MAGIC = b"NGSP"
#: The versions read (splat-transform reads 2-4 and writes 3 or 4).
VERSIONS = (2, 3, 4)
#: Gzip's first two bytes (versions 2 and 3 are one gzip stream).
GZIP_MAGIC = b"\x1f\x8b"
#: SPZ's DC colour scale: byte / 255 = f_dc · COLOR_SCALE + 0.5 (Niantic's ``colorScale``, not SH_C0).
COLOR_SCALE = 0.15
#: Header flags bit: extension records follow the attributes (v2/v3) or the 32-byte header (v4).
FLAG_EXTENSIONS = 0x2
#: ``SPZ_ADOBE_coordinate_system``'s record type; its payload is one uint32, an index into ``COORDINATE_SYSTEMS``.
COORDINATE_SYSTEM_EXTENSION = 0xADBE0003
#: Niantic's ``CoordinateSystem`` values 1-16 (``src/cc/splat-types.h``; 0 is UNSPECIFIED, the default RUB): the
#: directions of +x, +y, +z as Right/Left, Up/Down, Back/Front. The first eight are the "standard" family, the
#: last eight the "rotated" one (y and z swapped by a quarter turn about x).
COORDINATE_SYSTEMS = ("LDB", "RDB", "LUB", "RUB", "LDF", "RDF", "LUF", "RUF",
                      "LFD", "RFD", "LFU", "RFU", "LBD", "RBD", "LBU", "RBU")
#: The system values are read in (a file without a declaration; the spec's default).
DEFAULT_SYSTEM = "RUB"
#: The sign each standard-family letter gives its axis against RUB's.
_LETTER_SIGNS = {"R": 1.0, "L": -1.0, "U": 1.0, "D": -1.0, "B": 1.0, "F": -1.0}
#: From the rotated family to the standard one: a quarter turn about x, (x, y, z) -> (x, z, -y).
_ROTATED_TO_STANDARD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: The most extension-record bytes read: the known records are 4 and 12 bytes of descriptors; a stream holding more
#: after the attributes is damage (a wrong count or SH degree), not metadata.
MAX_EXTENSION_BYTES = 1 << 16
_HEADER = np.dtype([("magic", "<u4"), ("version", "<u4"), ("count", "<u4"), ("sh_degree", "u1"),
                    ("fractional_bits", "u1"), ("flags", "u1"), ("reserved", "u1")])
_V4_HEADER_SIZE = 32
_ALPHA_EPS = 1e-6
#: SH bytes per Gaussian by SH degree (3 channels × ((d + 1)² - 1) coefficients).
_SH_BYTES = (0, 9, 24, 45)
#: Bytes inflated per read of a Zstandard stream: memory grows with the data there is, never with what a
#: (possibly damaged) table of contents claims.
_ZSTD_PIECE = 1 << 24
#: Deflate expands at most 1032:1 (RFC 1951's longest match per code): a gzip stream of ``size`` bytes holds at
#: most this many times that, so a header claiming more is refused before anything is inflated.
MAX_DEFLATE_RATIO = 1032


def is_spz(head: bytes) -> bool:
    """True for the first bytes of an SPZ file: a version-4 header, or a gzip stream whose first bytes inflate to
    an SPZ header (``head`` should hold a few hundred bytes for that)."""
    if head.startswith(MAGIC):
        return True
    if not head.startswith(GZIP_MAGIC):
        return False
    try:
        return zlib.decompressobj(31).decompress(head, 4).startswith(MAGIC)
    except zlib.error:
        return False


def _sizes(n: int, version: int, degree: int) -> list:
    """Byte sizes of the attribute blocks (positions, alphas, colours, scales, rotations[, SH])."""
    sizes = [9 * n, n, 3 * n, 3 * n, (3 if version == 2 else 4) * n]
    return sizes + ([_SH_BYTES[degree] * n] if degree else [])


def _header(path, raw: bytes):
    if len(raw) < _HEADER.itemsize or not raw.startswith(MAGIC):
        raise SplatsError(path, "not an SPZ file: its (decompressed) header does not start with 'NGSP'", "header")
    h = np.frombuffer(raw[:_HEADER.itemsize], _HEADER)[0]
    version, n, degree = int(h["version"]), int(h["count"]), int(h["sh_degree"])
    if version not in VERSIONS:
        raise SplatsError(path, f"SPZ version {version} is not read (versions {VERSIONS[0]}-{VERSIONS[-1]} are): "
                                "write it again with a current SPZ writer (e.g. splat-transform)", "version")
    if degree >= len(_SH_BYTES):
        raise SplatsError(path, f"SPZ SH degree {degree} is not read (0-3 are)", "sh_degree")
    if int(h["fractional_bits"]) > 23:
        raise SplatsError(path, f"SPZ fractional bits {int(h['fractional_bits'])} leave no integer part (0-23)",
                          "fractional_bits")
    return version, n, degree, int(h["fractional_bits"])


def _flags(raw: bytes) -> int:
    return raw[_HEADER.fields["flags"][1]]


def read(path) -> GaussianPly:
    """Read an SPZ file (module docstring) as raw INRIA values in the frame of a file without a coordinate-system
    declaration (the docstring's convention); SplatsError naming the file if unusable."""
    path = os.fspath(path)
    data = read_bytes(path)
    if data.startswith(GZIP_MAGIC):
        version, n, degree, fb, blocks, system = _gzip_blocks(path, data)
    else:
        version, n, degree, fb, blocks, system = _zstd_blocks(path, data)
    ply = _decode(blocks, version, n, degree, fb)
    return _from_system(ply, system) if system not in (None, DEFAULT_SYSTEM) else ply


def system_matrix(system: str) -> np.ndarray:
    """(3, 3) M with p_RUB = M p for the values p of a file declaring ``system`` (a ``COORDINATE_SYSTEMS`` name), as
    Niantic's library packs and unpacks them (module docstring): the standard family's letter flips, for the rotated
    family those of the standard system eight values before, then a quarter turn about x."""
    index = COORDINATE_SYSTEMS.index(system)
    M = np.diag([_LETTER_SIGNS[letter] for letter in COORDINATE_SYSTEMS[index % 8]])
    return _ROTATED_TO_STANDARD @ M if index >= 8 else M


def _from_system(ply: GaussianPly, system: str) -> GaussianPly:
    """``ply`` whose values are in ``system``, turned into the default frame (module docstring)."""
    M = system_matrix(system)
    proper = np.linalg.det(M) * M   # a rotation: M R and det(M) M R give one covariance M Σ Mᵀ
    w, x, y, z = cameras.rotation_to_quaternion(proper)
    left = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])  # q -> m ⊗ q
    ply.xyz = (ply.xyz.astype(np.float64) @ M.T).astype(np.float32)
    ply.rot = (ply.rot.astype(np.float64) @ left.T).astype(np.float32)
    if ply.f_rest.shape[2]:
        rest = sh_rotation(M, ply.sh_degree)[1:, 1:]   # (K-1, K-1) on coefficient-major; f_rest is channel-major
        ply.f_rest = np.einsum("kj,ncj->nck", rest, ply.f_rest.astype(np.float64)).astype(np.float32)
    return ply


def _extensions(path, zone: bytes, where: str) -> str | None:
    """The coordinate system (a ``COORDINATE_SYSTEMS`` name) that the extension records ``zone`` declare, or None;
    other record types skipped by their length. ``where`` says where the records were, for the errors."""
    if len(zone) > MAX_EXTENSION_BYTES:
        raise SplatsError(path, f"SPZ extension records {where} are {len(zone):,} bytes, more than the "
                                f"{MAX_EXTENSION_BYTES:,} read (damaged file: a wrong count or SH degree?)", "extensions")
    at, system = 0, None
    while at < len(zone):
        if len(zone) - at < 8:
            raise SplatsError(path, f"SPZ extension record {where} at byte {at} is cut after {len(zone) - at} of its "
                                    "8 header bytes (type, length): damaged file", "extensions")
        kind, length = (int(v) for v in np.frombuffer(zone, "<u4", 2, at))
        if length > len(zone) - at - 8:
            raise SplatsError(path, f"SPZ extension record 0x{kind:08X} {where} claims {length:,} bytes, "
                                    f"{len(zone) - at - 8:,} remain: damaged file", "extensions")
        if kind == COORDINATE_SYSTEM_EXTENSION:
            value = int(np.frombuffer(zone, "<u4", 1, at + 8)[0]) if length == 4 else None
            if value is None or value > len(COORDINATE_SYSTEMS):
                raise SplatsError(path, f"SPZ_ADOBE_coordinate_system record {where} holds "
                                        f"{'value ' + str(value) if value is not None else f'{length} bytes'}, not "
                                        f"one uint32 of 0-{len(COORDINATE_SYSTEMS)} (a named coordinate system): "
                                        "damaged file, or a newer SPZ", "extensions")
            system = COORDINATE_SYSTEMS[value - 1] if value else None  # 0: UNSPECIFIED, the default
        at += 8 + length
    return system


def _gzip_blocks(path, data: bytes):
    """Versions 2 and 3: inflate the header, then exactly the bytes the header says follow (never more)."""
    d = zlib.decompressobj(31)
    try:
        head = d.decompress(data, _HEADER.itemsize)
        version, n, degree, fb = _header(path, head)
        if version == 4:
            raise SplatsError(path, "SPZ version 4 inside gzip: not a layout any writer makes", "version")
        sizes = _sizes(n, version, degree)
        if sum(sizes) > MAX_DEFLATE_RATIO * len(data):   # a forged count: refused without inflating (no bomb)
            raise SplatsError(path, f"SPZ file truncated: {n:,} Gaussians of SH degree {degree} need {sum(sizes):,} "
                                    f"bytes after the header, more than a gzip stream of {len(data):,} bytes can hold",
                              "count")
        body = d.decompress(d.unconsumed_tail, sum(sizes)) if sum(sizes) else b""
        if len(body) < sum(sizes):
            raise SplatsError(path, f"SPZ file truncated: {n:,} Gaussians of SH degree {degree} need "
                                    f"{sum(sizes):,} bytes after the header, the gzip stream holds {len(body):,}",
                              "count")
        # the stream must end where the header says (after the extension records when flagged): more data means a
        # wrong count or SH degree (the blocks would be read misaligned), no end a truncated file (checksum read too)
        flagged = bool(_flags(head) & FLAG_EXTENSIONS)
        limit = MAX_EXTENSION_BYTES + 1 if flagged else 64
        more = b""
        while not d.eof and len(more) < limit:   # (past the end, zlib keeps the rest as unused data)
            piece = d.decompress(d.unconsumed_tail, limit - len(more))
            if not piece:
                break
            more += piece
            if not flagged:
                break
        system = _extensions(path, more, "after the attributes") if flagged else None
        if more and not flagged:
            raise SplatsError(path, f"SPZ header says {n:,} Gaussians of SH degree {degree} ({sum(sizes):,} bytes "
                                    "after the header), but its gzip stream holds more: the count or SH degree is "
                                    "wrong (damaged file; extension records follow only when the header's flags "
                                    "say so)", "count")
        if not d.eof:
            raise SplatsError(path, "its gzip stream ends before its end marker and checksum: truncated SPZ file",
                              "header")
    except zlib.error as e:
        raise SplatsError(path, f"its gzip stream is corrupt ({e}): truncated or damaged SPZ file") from None
    return version, n, degree, fb, _split(body, sizes), system


def _split(body: bytes, sizes) -> list:
    out, at = [], 0
    for s in sizes:
        out.append(np.frombuffer(body, np.uint8, s, at))
        at += s
    return out


def _zstd_blocks(path, data: bytes):
    """Version 4: the 32-byte header, the table of contents, one Zstandard frame per attribute."""
    version, n, degree, fb = _header(path, data)
    if version != 4 or len(data) < _V4_HEADER_SIZE:
        raise SplatsError(path, f"SPZ version {version} without gzip: only version 4 is stored so", "version")
    sizes = _sizes(n, version, degree)
    streams = data[15]
    toc = int(np.frombuffer(data, "<u4", 1, 16)[0])
    if streams != len(sizes) or toc < _V4_HEADER_SIZE or toc + 16 * streams > len(data):
        raise SplatsError(path, f"SPZ version 4 header is inconsistent: {streams} streams at byte {toc} "
                                f"({len(sizes)} expected for SH degree {degree}, in a file of {len(data):,} bytes)",
                          "header")
    system = (_extensions(path, data[_V4_HEADER_SIZE:toc], "between the header and the table of contents")
              if _flags(data) & FLAG_EXTENSIONS else None)
    entries = np.frombuffer(data, "<u8", 2 * streams, toc).reshape(streams, 2)
    try:
        import zstandard  # bundled with Blender (its .blend compression) and pinned in requirements.txt
    except ImportError:
        raise SplatsError(path, "SPZ version 4 is Zstandard-compressed and this Python has no 'zstandard' module: "
                                "install it, or write the file as version 3 (splat-transform --spz-version 3)",
                          "version") from None
    at, blocks = toc + 16 * streams, []
    for i, ((packed, unpacked), want) in enumerate(zip(entries.tolist(), sizes)):
        if unpacked != want or at + packed > len(data):
            raise SplatsError(path, f"SPZ stream {i} claims {unpacked:,} bytes from {packed:,} at byte {at:,}; "
                                    f"{n:,} Gaussians need {want:,} (file of {len(data):,} bytes): damaged file",
                              "streams")
        pieces, got = [], 0
        try:
            with zstandard.ZstdDecompressor().stream_reader(memoryview(data)[at:at + packed]) as r:
                while got < want:
                    piece = r.read(min(_ZSTD_PIECE, want - got))
                    if not piece:
                        break
                    pieces.append(piece)
                    got += len(piece)
        except zstandard.ZstdError as e:
            raise SplatsError(path, f"SPZ stream {i} is not valid Zstandard data ({e})", "streams") from None
        raw = pieces[0] if len(pieces) == 1 else b"".join(pieces)
        if len(raw) != want:
            raise SplatsError(path, f"SPZ stream {i} holds {len(raw):,} bytes, its entry says {want:,}", "streams")
        blocks.append(np.frombuffer(raw, np.uint8))
        at += packed
    return version, n, degree, fb, blocks, system


def _byte_table(f) -> np.ndarray:
    """float32 values of the 256 bytes under ``f`` (float64 math, as the formulas state): decoding a byte array is
    then one lookup per byte."""
    return np.asarray(f(np.arange(256, dtype=np.float64)), np.float32)


_ALPHA_LOGIT = _byte_table(lambda b: np.log(np.clip(b / 255.0, _ALPHA_EPS, 1 - _ALPHA_EPS))
                           - np.log(1 - np.clip(b / 255.0, _ALPHA_EPS, 1 - _ALPHA_EPS)))
_COLOR = _byte_table(lambda b: (b / 255.0 - 0.5) / COLOR_SCALE)
_LOG_SCALE = _byte_table(lambda b: b / 16.0 - 10.0)
_SH = _byte_table(lambda b: (b - 128.0) / 128.0)


def _decode(blocks, version: int, n: int, degree: int, fb: int) -> GaussianPly:
    pos, alpha, color, scale, rot = blocks[:5]
    p = pos.reshape(n, 3, 3).astype(np.int32)
    fixed = p[..., 0] | (p[..., 1] << 8) | (p[..., 2] << 16)
    fixed -= (fixed & 0x800000) << 1  # sign-extend 24 bits
    xyz = (fixed.astype(np.float64) / float(1 << fb)).astype(np.float32)
    if version == 2:
        xyz_q = rot.reshape(n, 3).astype(np.float64) / 127.5 - 1.0
        w = np.sqrt(np.maximum(0.0, 1.0 - (xyz_q * xyz_q).sum(1)))
        q = np.concatenate([w[:, None], xyz_q], axis=1).astype(np.float32)
    else:
        q = _smallest_three(rot.view("<u4"))
    f_rest = np.zeros((n, 3, 0), np.float32)
    if degree:
        # coefficient-major bytes -> channel-major: transposed as bytes (a quarter of the float copy), then looked up
        sh = np.ascontiguousarray(blocks[5].reshape(n, _SH_BYTES[degree] // 3, 3).transpose(0, 2, 1))
        f_rest = _SH[sh]
    return GaussianPly(xyz=xyz, f_dc=_COLOR[color.reshape(n, 3)], f_rest=f_rest, opacity=_ALPHA_LOGIT[alpha],
                       scale=_LOG_SCALE[scale.reshape(n, 3)], rot=q, format="spz")


#: For the index of the largest component (x, y, z, w order), the other three from the lowest bits up.
_OTHERS = np.array([[3, 2, 1], [3, 2, 0], [3, 1, 0], [2, 1, 0]])


def _smallest_three(packed: np.ndarray) -> np.ndarray:
    """(N, 4) float32 quaternions (w, x, y, z) of SPZ v3/v4 rotation words (module docstring)."""
    packed = packed.astype(np.uint32)
    largest = (packed >> np.uint32(30)).astype(np.intp)
    xyzw = np.empty((len(packed), 4), np.float32)
    rows = np.arange(len(packed))
    total = np.zeros(len(packed), np.float32)
    step = np.float32(np.sqrt(0.5) / 511.0)
    for slot in range(3):
        bits = packed >> np.uint32(10 * slot)
        v = (bits & np.uint32(511)).astype(np.float32) * step
        v[(bits & np.uint32(512)) != 0] *= -1
        xyzw[rows, _OTHERS[largest, slot]] = v
        total += v * v
    xyzw[rows, largest] = np.sqrt(np.maximum(np.float32(0), 1 - total))
    return xyzw[:, [3, 0, 1, 2]]
