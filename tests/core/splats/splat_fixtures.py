"""Test helpers for core.splats.gaussians: writers of the formats the reader must understand, written from the formats'
descriptions (not from the reader).

* ``write_compressed_ply`` quantises known Gaussians the way SuperSplat's exporter does (playcanvas/supersplat
  ``src/splat-serialize.ts`` ``Chunk.pack``; the same rules in playcanvas/splat-transform
  ``src/lib/writers/compressed-chunk.ts``): per chunk of 256, min/max boxes (log scales clamped to [-20, 20]),
  t = (v - min) / (max - min) (0 when the range is below 1e-5), k = floor(t (2^bits - 1) + 0.5); positions and
  scales 11-10-11 bits (x high), colours 8-8-8-8 (r high, alpha = sigmoid(opacity) low), the quaternion as the
  index of its largest |component| in the top two bits and the other three, sign-flipped so that the largest is
  positive, as floor((q_j √2/2 + 0.5) · 1023 + 0.5) in file order; SH bytes trunc((v / 8 + 0.5) · 256) in 0..255.
* ``write_typed_ply`` writes any vertex (and optional face) layout with chosen PLY types, e.g. half floats in
  ``ushort`` slots or a mesh.

And the raw Gaussians the tests of ``core.splats.gaussians*`` and ``core.splats.trellis`` share: ``random_ply`` (INRIA values, SH 0-3,
optional normals and a label), ``random_gaussians`` (unit quaternions, SH beyond ±4), ``trellis_like_file`` (what
TRELLIS/Amodal3R's save_ply writes), ``write_compressed`` (a GaussianPly through ``write_compressed_ply``),
``assert_raw_equal`` (bit-exact) and ``same_rotation_error``.
"""

import numpy as np

from scpainter_blender.core.splats import gaussians as splats, trellis

SH_C0 = 0.28209479177387814
_NP = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4", "float": "f4",
       "double": "f8"}


def write_typed_ply(path, columns, byte_order="<", faces=None, comment=None):
    """PLY with one vertex element of ``columns`` = [(name, ply_type, values)], optionally triangle ``faces``."""
    n = len(columns[0][2]) if columns else 0
    arr = np.empty(n, dtype=[(name, byte_order + _NP[t]) for name, t, _ in columns])
    for name, _, values in columns:
        arr[name] = values
    head = ["ply", f"format binary_{'little' if byte_order == '<' else 'big'}_endian 1.0"]
    head += [f"comment {comment}"] if comment else []
    head += [f"element vertex {n}"] + [f"property {t} {name}" for name, t, _ in columns]
    body = arr.tobytes()
    if faces is not None:
        faces = np.asarray(faces, np.int32)
        head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        rec = np.empty(len(faces), dtype=[("n", "u1"), ("idx", byte_order + "i4", (3,))])
        rec["n"], rec["idx"] = 3, faces
        body += rec.tobytes()
    head.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii") + body)


def inria_columns(ply, ply_type="float", cast=None):
    """The required INRIA columns of a GaussianPly (+ f_rest), each as ``ply_type`` values ``cast(v)``."""
    cast = cast or (lambda v: v)
    N, K1 = len(ply.xyz), ply.f_rest.shape[2]
    cols = [(k, ply_type, cast(ply.xyz[:, i])) for i, k in enumerate("xyz")]
    cols += [(f"f_dc_{i}", ply_type, cast(ply.f_dc[:, i])) for i in range(3)]
    flat = ply.f_rest.reshape(N, 3 * K1)
    cols += [(f"f_rest_{i}", ply_type, cast(flat[:, i])) for i in range(3 * K1)]
    cols += [("opacity", ply_type, cast(ply.opacity))]
    cols += [(f"scale_{i}", ply_type, cast(ply.scale[:, i])) for i in range(3)]
    cols += [(f"rot_{i}", ply_type, cast(ply.rot[:, i])) for i in range(4)]
    return cols


def _pack_unorm(t, bits):
    top = (1 << bits) - 1
    return np.clip(np.floor(np.asarray(t, np.float64) * top + 0.5), 0, top).astype(np.uint32)


def _normalise(v, lo, hi):
    v = np.asarray(v, np.float64)
    rng = hi - lo
    t = np.where(rng < 1e-5, 0.0, (v - lo) / np.where(rng < 1e-5, 1.0, rng))
    return np.where(v <= lo, 0.0, np.where(v >= hi, 1.0, t))


def pack_rotation(q):
    """SuperSplat's 2-10-10-10 word for quaternions (N, 4) in file order (w, x, y, z)."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    largest = np.argmax(np.abs(q), axis=1)  # first index on ties, as the writer's strict '>' scan
    q = np.where(q[np.arange(len(q)), largest][:, None] < 0, -q, q)
    words = []
    for qi, big in zip(q, largest):
        w = int(big)
        for j in range(4):
            if j != big:
                w = (w << 10) | int(_pack_unorm(qi[j] * np.sqrt(0.5) + 0.5, 10))
        words.append(w)
    return np.array(words, np.uint32)


def write_compressed_ply(path, xyz, log_scale, quat, f_dc, opacity_logit, f_rest=None, chunk_colors=True):
    """Write a SuperSplat compressed PLY of the given raw Gaussians (module docstring); returns the chunk table
    (C, 12 or 18) as written, for computing quantisation steps."""
    xyz, log_scale, f_dc = (np.asarray(a, np.float64) for a in (xyz, log_scale, f_dc))
    N = len(xyz)
    C = -(-N // 256)
    colour = 0.5 + SH_C0 * f_dc
    alpha = 1.0 / (1.0 + np.exp(-np.asarray(opacity_logit, np.float64)))
    table = np.zeros((C, 18 if chunk_colors else 12), np.float32)
    packed = np.zeros((N, 4), np.uint32)
    for c in range(C):
        s = slice(c * 256, min(N, (c + 1) * 256))
        lo_p, hi_p = xyz[s].min(0), xyz[s].max(0)
        lo_s, hi_s = np.clip(log_scale[s].min(0), -20, 20), np.clip(log_scale[s].max(0), -20, 20)
        # the file stores float32 ranges; quantise against them
        lo_p, hi_p, lo_s, hi_s = (np.float32(a).astype(np.float64) for a in (lo_p, hi_p, lo_s, hi_s))
        tp = [_normalise(xyz[s, i], lo_p[i], hi_p[i]) for i in range(3)]
        ts = [_normalise(log_scale[s, i], lo_s[i], hi_s[i]) for i in range(3)]
        packed[s, 0] = _pack_unorm(tp[0], 11) << 21 | _pack_unorm(tp[1], 10) << 11 | _pack_unorm(tp[2], 11)
        packed[s, 2] = _pack_unorm(ts[0], 11) << 21 | _pack_unorm(ts[1], 10) << 11 | _pack_unorm(ts[2], 11)
        row = list(lo_p) + list(hi_p) + list(lo_s) + list(hi_s)
        if chunk_colors:
            lo_c = np.float32(colour[s].min(0)).astype(np.float64)
            hi_c = np.float32(colour[s].max(0)).astype(np.float64)
            tc = [_normalise(colour[s, i], lo_c[i], hi_c[i]) for i in range(3)]
            row += list(lo_c) + list(hi_c)
        else:
            tc = [np.clip(colour[s, i], 0, 1) for i in range(3)]
        packed[s, 3] = (_pack_unorm(tc[0], 8) << 24 | _pack_unorm(tc[1], 8) << 16 | _pack_unorm(tc[2], 8) << 8
                        | _pack_unorm(alpha[s], 8))
        table[c] = row
    packed[:, 1] = pack_rotation(quat)
    names = ["min_x", "min_y", "min_z", "max_x", "max_y", "max_z", "min_scale_x", "min_scale_y", "min_scale_z",
             "max_scale_x", "max_scale_y", "max_scale_z"]
    names += ["min_r", "min_g", "min_b", "max_r", "max_g", "max_b"] if chunk_colors else []
    head = ["ply", "format binary_little_endian 1.0", "comment test encoder", f"element chunk {C}"]
    head += [f"property float {n}" for n in names]
    head += [f"element vertex {N}"] + [f"property uint packed_{n}" for n in ("position", "rotation", "scale",
                                                                               "color")]
    body = table.astype("<f4").tobytes() + packed.astype("<u4").tobytes()
    if f_rest is not None and f_rest.shape[2]:
        flat = np.asarray(f_rest, np.float64).reshape(N, -1)
        head += [f"element sh {N}"] + [f"property uchar f_rest_{i}" for i in range(flat.shape[1])]
        body += np.clip(np.trunc((flat / 8 + 0.5) * 256), 0, 255).astype(np.uint8).tobytes()
    head.append("end_header")
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii") + body)
    return table


# -- raw Gaussians shared by the tests -----------------------------------------------------------------------------

def random_ply(N=50, degree=0, seed=0, extras=True):
    rng = np.random.default_rng(seed)
    K1 = splats.num_sh_coefficients(degree) - 1
    extra = {}
    if extras:
        extra = {"nx": np.zeros(N, np.float32), "ny": np.zeros(N, np.float32), "nz": np.zeros(N, np.float32),
                 "label": rng.integers(0, 255, N).astype(np.uint8)}
    return splats.GaussianPly(
        xyz=rng.normal(0, 1, (N, 3)).astype(np.float32), f_dc=rng.normal(0, 1, (N, 3)).astype(np.float32),
        f_rest=rng.normal(0, 0.2, (N, 3, K1)).astype(np.float32), opacity=rng.normal(0, 2, N).astype(np.float32),
        scale=rng.normal(-4, 1, (N, 3)).astype(np.float32), rot=rng.normal(0, 1, (N, 4)).astype(np.float32),
        extra=extra)


def trellis_like_file(path, N=40, seed=1):
    """What TRELLIS/Amodal3R's save_ply writes: 17 float properties, zero normals, SH degree 0, unit-cube object."""
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    arr = np.zeros(N, dtype=[(n, "<f4") for n in names])
    zup = rng.uniform(-0.5, 0.5, (N, 3))
    filexyz = zup @ trellis.ZUP_TO_TRELLIS_FILE.T
    for i, k in enumerate("xyz"):
        arr[k] = filexyz[:, i]
    for i in range(3):
        arr[f"f_dc_{i}"] = rng.normal(0, 1, N)
        arr[f"scale_{i}"] = np.log(rng.uniform(0.002, 0.02, N))
    arr["opacity"] = rng.normal(2, 1, N)
    q = rng.normal(0, 1, (N, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    for i in range(4):
        arr[f"rot_{i}"] = q[:, i]
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % N
    header += "".join(f"property float {n}\n" for n in names) + "end_header\n"
    with open(path, "wb") as f:
        f.write(header.encode() + arr.tobytes())
    return zup, arr


def assert_raw_equal(a, b):
    """Two GaussianPly hold the same raw values bit for bit (NaN included) and the same extras, in order."""
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.shape == y.shape and x.dtype == y.dtype, k
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), k  # bit-exact, NaN included
    assert list(a.extra) == list(b.extra)
    for k in a.extra:
        assert a.extra[k].dtype == b.extra[k].dtype and np.array_equal(a.extra[k], b.extra[k]), k


def random_gaussians(N, degree, seed):
    """Raw INRIA values, quaternions unit; some SH values beyond the compressed format's ±4 range."""
    rng = np.random.default_rng(seed)
    q = rng.normal(0, 1, (N, 4))
    K1 = splats.num_sh_coefficients(degree) - 1
    return splats.GaussianPly(
        xyz=rng.normal(0, 2, (N, 3)).astype(np.float32), f_dc=rng.normal(0, 1, (N, 3)).astype(np.float32),
        f_rest=rng.normal(0, 2, (N, 3, K1)).astype(np.float32), opacity=rng.normal(0, 3, N).astype(np.float32),
        scale=rng.normal(-4, 1, (N, 3)).astype(np.float32),
        rot=(q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32))


def write_compressed(path, ply, chunk_colors=True):
    return write_compressed_ply(path, ply.xyz, ply.scale, ply.rot, ply.f_dc, ply.opacity, ply.f_rest,
                                  chunk_colors=chunk_colors)


def same_rotation_error(a, b):
    """Largest distance between unit quaternions a and b (N, 4) taken up to sign (q and -q are one rotation)."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.minimum(np.abs(a - b).max(1), np.abs(a + b).max(1)).max()


# -- writers of the formats issue 31 added (shared by their tests and tests/fuzz_splat_formats.py) ------------------

def spz_body(ply, version=2, fractional_bits=12, count=None, degree=None, flags=0, extensions=b"") -> bytes:
    """The uncompressed bytes of an SPZ file (header and attributes; version 2 or 3) of raw INRIA values ``ply``, from
    the format's description (nianticlabs/spz, src/cc/load-spz.cc: packGaussians). Version 2: rotations as 3 bytes
    x y z of the unit quaternion with w >= 0, byte = round((v + 1) · 127.5); version 3: "smallest three" in a uint32
    (bits 30-31 the index of the largest |component| in x y z w order, made positive; the other three from bit 0 up
    in decreasing index order, 9 bits of |v| / √½ · 511 and a sign bit). ``count`` / ``degree``: header values other
    than the data's (for damaged files). ``flags``: the header's flags byte; ``extensions``: extension records
    (``spz_extension``) after the attributes, as Niantic's serializer writes them (set flags bit 0x2 with them)."""
    n, deg = len(ply), ply.sh_degree
    header = np.array([(0x5053474E, version, n if count is None else count, deg if degree is None else degree,
                        fractional_bits, flags, 0)],
                      [("m", "<u4"), ("v", "<u4"), ("n", "<u4"), ("d", "u1"), ("fb", "u1"), ("f", "u1"), ("r", "u1")])
    return header.tobytes() + b"".join(_spz_blocks(ply, version, fractional_bits)) + extensions


def spz_v4(ply, fractional_bits=12, flags=0, extensions=b"") -> bytes:
    """An SPZ version 4 file of raw INRIA values ``ply`` (nianticlabs/spz README, "File layout (version 4)"): the
    32-byte plain header (magic, version, N, SH degree, fractional bits, flags, number of streams, uint32 offset of
    the table of contents, 12 reserved zero bytes), the extension records ``extensions`` (flags bit 0x2 says they are
    there), the table (per stream uint64 compressed, uint64 uncompressed size), one Zstandard frame per attribute."""
    import struct

    import zstandard

    blocks = _spz_blocks(ply, 4, fractional_bits)
    frames = [zstandard.ZstdCompressor().compress(b) for b in blocks]
    toc = 32 + len(extensions)
    header = struct.pack("<IIIBBBBI12x", 0x5053474E, 4, len(ply), ply.sh_degree, fractional_bits, flags,
                         len(blocks), toc)
    table = b"".join(struct.pack("<QQ", len(f), len(b)) for f, b in zip(frames, blocks))
    return header + extensions + table + b"".join(frames)


def spz_extension(kind: int, payload: bytes) -> bytes:
    """One SPZ extension record (nianticlabs/spz extensions/README.md): uint32 type, uint32 length, the payload."""
    import struct

    return struct.pack("<II", kind, len(payload)) + payload


def spz_coordinate_system(value: int) -> bytes:
    """An ``SPZ_ADOBE_coordinate_system`` record (type 0xADBE0003) declaring Niantic's CoordinateSystem ``value``."""
    import struct

    return spz_extension(0xADBE0003, struct.pack("<I", value))


def _spz_blocks(ply, version, fractional_bits) -> list:
    """The attribute blocks (positions, alphas, colours, scales, rotations[, SH]) as ``spz_body`` describes them."""
    from scpainter_blender.core.splats import spz

    n = len(ply)
    fixed = np.rint(ply.xyz.astype(np.float64) * (1 << fractional_bits)).astype(np.int64) & 0xFFFFFF
    pos = np.stack([(fixed >> s) & 0xFF for s in (0, 8, 16)], axis=-1).astype(np.uint8)
    byte = lambda v: np.clip(np.rint(v), 0, 255).astype(np.uint8)  # noqa: E731
    alpha = byte(splats.opacities_from_logits(ply.opacity) * 255)
    color = byte((ply.f_dc.astype(np.float64) * spz.COLOR_SCALE + 0.5) * 255)
    scale = byte((ply.scale.astype(np.float64) + 10) * 16)
    q = splats.unit_quaternions(ply.rot)
    if version == 2:
        q *= np.where(q[:, :1] < 0, -1.0, 1.0)
        rot = byte((q[:, 1:] + 1) * 127.5)
    else:
        xyzw = q[:, [1, 2, 3, 0]].astype(np.float64)
        largest = np.argmax(np.abs(xyzw), axis=1)
        xyzw *= np.where(xyzw[np.arange(n), largest] < 0, -1.0, 1.0)[:, None]
        word = largest.astype(np.uint32) << np.uint32(30)
        for slot in range(3):
            # the other components in decreasing index order, from the lowest bits up
            comp = np.array([[i for i in (3, 2, 1, 0) if i != k][slot] for k in largest], np.intp)
            v = xyzw[np.arange(n), comp]
            m = np.minimum(np.rint(np.abs(v) / np.sqrt(0.5) * 511), 511).astype(np.uint32)
            word |= (m | np.where(v < 0, np.uint32(512), np.uint32(0))) << np.uint32(10 * slot)
        rot = word.astype("<u4")
    sh = byte(np.swapaxes(ply.f_rest, 1, 2).astype(np.float64) * 128 + 128)  # coefficient-major, channel inner
    return [a.tobytes() for a in (pos, alpha, color, scale, rot) + ((sh,) if sh.size else ())]


def write_spz(path, ply, version=2, fractional_bits=12):
    """An SPZ file (gzip, version 2 or 3) of raw INRIA values ``ply`` (``spz_body``)."""
    import gzip

    with open(path, "wb") as f:
        f.write(gzip.compress(spz_body(ply, version, fractional_bits)))


def write_ksplat(path, ply, level, sections=(0.6, 0.4), capacity=64, partial=(7, 5), spare=3, sh_range=(0, 0)):
    """A .ksplat of raw INRIA values ``ply`` (SH degree 0-2) from the format's description: the Gaussians split
    into sections by the shares ``sections``, each with ``spare`` unused slots; at levels 1-2 each section's first
    Gaussians fill full buckets of ``capacity`` in order and the last ones partial buckets of the sizes
    ``partial``; a bucket's centre is the middle of its Gaussians' box, the block size twice the largest offset."""
    n, degree = len(ply), ply.sh_degree
    counts = [int(round(s * n)) for s in sections[:-1]]
    counts.append(n - sum(counts))
    sh_n = (0, 9, 24)[degree]
    from scpainter_blender.core.splats import ksplat

    rec = ksplat.record_dtype(level, degree)
    main = np.zeros(ksplat.MAIN_HEADER, np.uint8)
    main[0], main[1] = 0, 1  # version 0.1
    u32 = main[:24].view("<u4")
    u32[1], u32[2], u32[3], u32[4] = len(counts), len(counts), n + spare * len(counts), n
    main[20:22].view("<u2")[0] = level
    main[36:44].view("<f4")[:] = sh_range
    headers, blobs, at = [], [], 0
    lo, hi = (sh_range[0] or -1.5), (sh_range[1] or 1.5)
    q_range = 32767
    for m in counts:
        sel = slice(at, at + m)
        at += m
        hdr = np.zeros(ksplat.SECTION_HEADER, np.uint8)
        h32, hf = hdr.view("<u4"), hdr.view("<f4")
        r = np.zeros(m + spare, rec)
        xyz = ply.xyz[sel].astype(np.float64)
        bucket_bytes = b""
        h32[0], h32[1] = m, m + spare
        if level:
            n_full = (m - sum(partial)) // capacity
            sizes = [capacity] * n_full + [m - n_full * capacity - sum(partial)] * (m - n_full * capacity > sum(
                partial)) + list(partial)
            parts = sizes[n_full:]
            bounds = np.cumsum([0] + sizes)
            idx = np.repeat(np.arange(len(sizes)), sizes)
            centres = np.array([(xyz[a:b].min(0) + xyz[a:b].max(0)) / 2 for a, b in zip(bounds[:-1], bounds[1:])],
                               np.float32)
            block = float(np.abs(xyz - centres[idx]).max()) * 2 * 1.001
            r["xyz"][:m] = np.clip(np.rint((xyz - centres[idx]) * (q_range / (block / 2))) + q_range, 0, 65535)
            h32[2], h32[3] = capacity, len(sizes)
            hf[4] = block
            hdr[20:22].view("<u2")[0] = 12  # bytes per bucket: its centre, 3 float32
            h32[6], h32[8], h32[9] = q_range, n_full, len(parts)
            bucket_bytes = np.array(parts, "<u4").tobytes() + centres.tobytes()
        else:
            r["xyz"][:m] = xyz
        hdr[40:42].view("<u2")[0] = degree
        headers.append(hdr.tobytes())
        r["scale"][:m] = np.exp(ply.scale[sel].astype(np.float64))
        r["rot"][:m] = splats.unit_quaternions(ply.rot[sel])
        rgba = np.concatenate([0.5 + SH_C0 * ply.f_dc[sel].astype(np.float64),
                               splats.opacities_from_logits(ply.opacity[sel])[:, None]], 1)
        r["rgba"][:m] = np.clip(np.rint(rgba * 255), 0, 255)
        if degree:
            # band by band, each band channel-major (r1 r2 r3 g1 g2 g3 b1 b2 b3, then five per channel)
            fr = ply.f_rest[sel].astype(np.float64)
            stored = np.concatenate([fr[:, :, a:b].reshape(m, -1) for a, b in ((0, 3), (3, 8))[:degree]], 1)
            if level == 2:
                stored = np.clip(np.rint((stored - lo) / (hi - lo) * 255), 0, 255)
            r["sh"][:m] = stored[:, :sh_n]
        blobs.append(bucket_bytes + r.tobytes())
    with open(path, "wb") as f:
        f.write(main.tobytes() + b"".join(headers) + b"".join(blobs))




def gltf_splats(ply, node_tree, buffer_uri=None, required=()):
    """(glTF JSON dict, buffer bytes) of one KHR_gaussian_splatting primitive of ``ply`` (raw INRIA values):
    POSITION and ROTATION interleaved in one view (stride 28), OPACITY as normalised unsigned bytes, SH degree
    coefficients as VEC3 floats; ``node_tree`` the glTF nodes (the mesh on the last); the buffer at ``buffer_uri``
    (None: a GLB's BIN chunk, ``glb``)."""
    n, K1 = len(ply), ply.f_rest.shape[2]
    q = splats.unit_quaternions(ply.rot)
    inter = np.zeros((n, 7), np.float32)
    inter[:, :3], inter[:, 3:] = ply.xyz, q[:, [1, 2, 3, 0]]
    parts = [inter.tobytes(), np.exp(ply.scale.astype(np.float64)).astype(np.float32).tobytes(),
             np.rint(splats.opacities_from_logits(ply.opacity) * 255).astype(np.uint8).tobytes(),
             ply.f_dc.astype(np.float32).tobytes()]
    sh = np.swapaxes(ply.f_rest, 1, 2)  # (n, K-1, 3)
    parts += [np.ascontiguousarray(sh[:, k]).astype(np.float32).tobytes() for k in range(K1)]
    views, blob = [], b""
    for p in parts:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(p)})
        blob += p + bytes(-len(p) % 4)
    views[0]["byteStride"] = 28

    def A(v, t, c=5126, off=0, **kw):  # an accessor of view v, type t, componentType c (float by default)
        return dict(bufferView=v, componentType=c, count=n, type=t, byteOffset=off, **kw)

    accessors = [A(0, "VEC3"), A(0, "VEC4", off=12), A(1, "VEC3"), A(2, "SCALAR", 5121, normalized=True), A(3, "VEC3")]
    accessors += [A(4 + k, "VEC3") for k in range(K1)]
    pfx = "KHR_gaussian_splatting:"
    attrs = {"POSITION": 0, pfx + "ROTATION": 1, pfx + "SCALE": 2, pfx + "OPACITY": 3, pfx + "SH_DEGREE_0_COEF_0": 4}
    k = 0
    for d in range(1, ply.sh_degree + 1):
        for c in range(2 * d + 1):
            attrs[f"{pfx}SH_DEGREE_{d}_COEF_{c}"] = 5 + k
            k += 1
    buffer = {"byteLength": len(blob)}
    if buffer_uri is not None:
        buffer["uri"] = buffer_uri
    tree = {"asset": {"version": "2.0"}, "extensionsUsed": ["KHR_gaussian_splatting"],
            "extensionsRequired": list(required), "scene": 0, "scenes": [{"nodes": [0]}], "nodes": node_tree,
            "meshes": [{"primitives": [{"attributes": attrs, "mode": 0,
                                         "extensions": {"KHR_gaussian_splatting": {"kernel": "ellipse"}}}]}],
            "buffers": [buffer], "bufferViews": views, "accessors": accessors}
    return tree, blob


def glb(tree: dict, binary: bytes) -> bytes:
    """A GLB of a glTF JSON dict and its BIN chunk (each chunk padded to 4 bytes: JSON with spaces, BIN with zeros)."""
    import json
    import struct

    j = json.dumps(tree).encode()
    j += b" " * (-len(j) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(j), 0x4E4F534A) + j + struct.pack("<II", len(binary), 0x004E4942) + binary
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


#: A source for the tests against the real writer (splat-transform) that needs no real file: written by
#: ``source_ply``, so those tests run wherever Node is, ``../shared/realdata`` or not.
GENERATED = "generated"


def source_ply(rel: str, folder) -> str:
    """The path of a source PLY for a real-writer test: the real file ``rel`` (``tests_support.realdata``: the test
    skips when it is absent), or for ``GENERATED`` 500 random Gaussians of SH degree 3 written into ``folder``."""
    import os

    from tests_support import realdata
    from scpainter_blender.core.splats import inria

    if rel != GENERATED:
        return realdata(rel)
    path = os.path.join(folder, "generated.ply")
    if not os.path.exists(path):
        inria.write_ply(path, random_ply(N=500, degree=3, seed=11, extras=False))
    return path
