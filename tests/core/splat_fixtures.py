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
