"""3D Gaussian Splatting PLY files: read, write, decode, and evaluate their spherical harmonics.

File layout (INRIA, graphdeco-inria/gaussian-splatting): one ``vertex`` element with float properties
``x y z [nx ny nz] f_dc_0..2 [f_rest_0..M-1] opacity scale_0..2 rot_0..3``, binary little- or big-endian, where

* ``opacity`` is a logit (decoded with a sigmoid), ``scale_*`` are natural logs (decoded with exp),
* ``rot_*`` is a quaternion (w, x, y, z), not necessarily unit (decoded by normalising),
* ``f_rest`` holds SH degree d >= 1 coefficients channel-major: M = 3 ((d+1)^2 - 1), first all of red's
  coefficients 1..K-1, then green's, then blue's. Colour = max(0.5 + Σ_k SH_k(dir) c_k, 0), dir = normalise(mean -
  camera centre).

TRELLIS / Amodal3R write the same layout with SH degree 0 (17 properties, zero normals), the object inside the
unit cube [-0.5, 0.5]^3, and positions/rotations multiplied by ``TRELLIS_FILE_FROM_ZUP`` (the file holds
(x, -z, y) of their Z-up frame). Everything else decodes exactly like an INRIA file.

Raw values (``GaussianPly``) are kept apart from decoded ones (``Gaussians``) so that write -> read is bit-exact.
Rows with NaN/inf, zero quaternions or scales that overflow are dropped on decoding and counted, never passed on.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np

#: File axes from TRELLIS's Z-up object axes: p_file = TRELLIS_FILE_FROM_ZUP @ p (a -90° turn about X undoes it).
TRELLIS_FILE_FROM_ZUP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
            "rot_0", "rot_1", "rot_2", "rot_3")
MAX_HEADER = 1 << 16
_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
          "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
          "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}

# Real spherical-harmonic basis constants as used by 3DGS renderers (degree 0-3).
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


class SplatsError(ValueError):
    """A Gaussian PLY that cannot be used; the message names the file and what is wrong."""

    def __init__(self, path, message):
        self.path = str(path)
        super().__init__(f"{os.path.basename(self.path)}: {message} ({self.path})")


def num_sh_coefficients(degree: int) -> int:
    return (degree + 1) ** 2


@dataclass
class GaussianPly:
    """Raw per-Gaussian values exactly as stored (float32), N rows.

    ``f_rest`` is (N, 3, K - 1): channel-major, as in the file. ``extra`` keeps any other vertex properties
    (normals, per-splat labels...) in file order so a rewrite loses nothing; decoding ignores them.
    """

    xyz: np.ndarray
    f_dc: np.ndarray
    f_rest: np.ndarray
    opacity: np.ndarray
    scale: np.ndarray
    rot: np.ndarray
    extra: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.xyz)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.f_rest.shape[2] + 1))) - 1


@dataclass
class Gaussians:
    """Decoded Gaussians in the file's object frame.

    ``means`` (N, 3); ``scales`` (N, 3) standard deviations along the local axes; ``quats`` (N, 4) unit (w, x, y, z);
    ``opacities`` (N,) in [0, 1]; ``sh`` (N, K, 3) coefficient-major (``sh[:, 0]`` is the DC term). All float32.
    ``dropped`` counts the rows left out on decoding, by reason.
    """

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray
    dropped: dict = field(default_factory=dict)

    def __len__(self):
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    def base_colors(self) -> np.ndarray:
        """View-independent colour (the DC term only), (N, 3) in [0, ...)."""
        return np.maximum(SH_C0 * self.sh[:, 0] + 0.5, 0.0).astype(np.float32)

    def extents(self):
        """Axis-aligned bounds (min (3,), max (3,)) of the means; zeros for an empty set."""
        if not len(self):
            return np.zeros(3), np.zeros(3)
        return self.means.min(axis=0).astype(np.float64), self.means.max(axis=0).astype(np.float64)


# --------------------------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------------------------

def _parse_header(raw: bytes, path):
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply"):
        raise SplatsError(path, "not a PLY file (it does not start with 'ply')")
    if end < 0:
        raise SplatsError(path, f"no 'end_header' in the first {MAX_HEADER} bytes")
    nl = raw.find(b"\n", end)
    if nl < 0:
        raise SplatsError(path, "the header ends without a newline (truncated file?)")
    try:
        lines = raw[:end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise SplatsError(path, "the header is not ASCII text") from None
    fmt, elements = None, []
    for n, line in enumerate(lines[1:], start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3:
                raise SplatsError(path, f"header line {n}: malformed format line {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not re.fullmatch(r"\d{1,15}", words[2]):
                raise SplatsError(path, f"header line {n}: malformed element line {line!r}")
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property":
            if not elements:
                raise SplatsError(path, f"header line {n}: property before any element")
            if len(words) >= 2 and words[1] == "list":
                elements[-1][2].append((words[-1], None))
                continue
            if len(words) != 3 or words[1] not in _TYPES:
                raise SplatsError(path, f"header line {n}: unknown property {line!r}")
            names = [p[0] for p in elements[-1][2]]
            if words[2] in names:
                raise SplatsError(path, f"header line {n}: property {words[2]!r} appears twice")
            elements[-1][2].append((words[2], _TYPES[words[1]]))
        else:
            raise SplatsError(path, f"header line {n}: unexpected {words[0]!r}")
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise SplatsError(path, f"format {fmt!r} is not supported: expected binary_little_endian or "
                                "binary_big_endian (ASCII splat files are not used in practice)")
    return fmt, elements, nl + 1


def read_ply(path) -> GaussianPly:
    """Read a Gaussian-splat PLY (INRIA or TRELLIS/Amodal3R) into raw float32 arrays; SplatsError if unusable."""
    path = os.fspath(path)
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(MAX_HEADER)
            fmt, elements, start = _parse_header(head, path)
            order = "<" if fmt == "binary_little_endian" else ">"
            offset = start
            for name, count, props in elements:
                if name == "vertex":
                    break
                if any(t is None for _, t in props):
                    raise SplatsError(path, f"element {name!r} before 'vertex' has list properties")
                offset += count * sum(np.dtype(t).itemsize for _, t in props)
            else:
                raise SplatsError(path, "no 'vertex' element")
            if any(t is None for _, t in props):
                raise SplatsError(path, "the 'vertex' element has list properties")
            dtype = np.dtype([(p, order + t) for p, t in props])
            need = count * dtype.itemsize
            if offset + need > size:
                raise SplatsError(path, f"truncated: the header promises {count} Gaussians "
                                        f"({need} bytes from byte {offset}) but the file has {size} bytes")
            f.seek(offset)
            data = np.frombuffer(f.read(need), dtype=dtype, count=count)
    except FileNotFoundError:
        raise SplatsError(path, "file not found") from None
    except OSError as e:
        raise SplatsError(path, f"cannot be read: {e}") from None
    return _from_structured(data, [p for p, _ in props], path)


def _from_structured(data, names, path) -> GaussianPly:
    missing = [k for k in REQUIRED if k not in names]
    if missing:
        raise SplatsError(path, f"missing required properties {missing}")
    rest = sorted((n for n in names if n.startswith("f_rest_")), key=lambda n: int(n[7:]) if n[7:].isdigit() else -1)
    if rest and [n[7:] for n in rest] != [str(i) for i in range(len(rest))]:
        raise SplatsError(path, f"f_rest properties must be numbered 0..{len(rest) - 1} without gaps")
    valid = {3 * (num_sh_coefficients(d) - 1): d for d in range(4)}
    if len(rest) not in valid:
        raise SplatsError(path, f"{len(rest)} f_rest properties: expected 0, 9, 24 or 45 (SH degree 0-3)")

    def cols(keys):  # doubles beyond float32's range become inf here, and are dropped on decoding
        out = np.empty((len(data), len(keys)), np.float32)
        with np.errstate(invalid="ignore", over="ignore"):
            for i, k in enumerate(keys):
                out[:, i] = data[k]
        return out

    K1 = len(rest) // 3
    used = set(REQUIRED) | set(rest)
    return GaussianPly(
        xyz=cols(["x", "y", "z"]), f_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        f_rest=cols(rest).reshape(len(data), 3, K1), opacity=cols(["opacity"])[:, 0],
        scale=cols(["scale_0", "scale_1", "scale_2"]), rot=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        extra={n: data[n].astype(data.dtype[n].newbyteorder("=")) for n in names if n not in used})


# --------------------------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------------------------

def write_ply(path, ply: GaussianPly, byte_order: str = "<", comment: str | None = None) -> None:
    """Write ``ply`` in the INRIA layout (float32; extras in their own types), atomically (temp file, rename).

    Property order: x y z, normals if present among the extras, f_dc, f_rest, opacity, scale, rot, other extras.
    """
    if byte_order not in "<>":
        raise ValueError("byte_order must be '<' or '>'")
    N = len(ply)
    K1 = ply.f_rest.shape[2]
    normals = [n for n in ("nx", "ny", "nz") if n in ply.extra]
    others = [n for n in ply.extra if n not in normals]
    fields = [("x", "f4"), ("y", "f4"), ("z", "f4")] + [(n, ply.extra[n].dtype.str[1:]) for n in normals]
    fields += [(f"f_dc_{i}", "f4") for i in range(3)] + [(f"f_rest_{i}", "f4") for i in range(3 * K1)]
    fields += [("opacity", "f4")] + [(f"scale_{i}", "f4") for i in range(3)] + [(f"rot_{i}", "f4") for i in range(4)]
    fields += [(n, ply.extra[n].dtype.str[1:]) for n in others]
    arr = np.empty(N, dtype=[(n, byte_order + t) for n, t in fields])
    for i, k in enumerate("xyz"):
        arr[k] = ply.xyz[:, i]
    for i in range(3):
        arr[f"f_dc_{i}"] = ply.f_dc[:, i]
        arr[f"scale_{i}"] = ply.scale[:, i]
    flat_rest = ply.f_rest.reshape(N, 3 * K1)
    for i in range(3 * K1):
        arr[f"f_rest_{i}"] = flat_rest[:, i]
    arr["opacity"] = ply.opacity
    for i in range(4):
        arr[f"rot_{i}"] = ply.rot[:, i]
    for n in normals + others:
        arr[n] = ply.extra[n]
    names = {v: k for k, v in _TYPES.items() if k in ("char", "uchar", "short", "ushort", "int", "uint", "float",
                                                         "double")}
    header = ["ply", f"format binary_{'little' if byte_order == '<' else 'big'}_endian 1.0"]
    if comment:
        header.append(f"comment {comment}")
    header.append(f"element vertex {N}")
    header += [f"property {names[t]} {n}" for n, t in fields]
    header.append("end_header")
    path = os.fspath(path)
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(arr.tobytes())
    os.replace(tmp, path)


# --------------------------------------------------------------------------------------------------------------
# Decoding and encoding
# --------------------------------------------------------------------------------------------------------------

def decode(ply: GaussianPly) -> Gaussians:
    """Activate raw values: exp scales, sigmoid opacity, normalised quaternions; drop and count bad rows.

    A row is dropped for any NaN/inf among its used values ("non_finite"), a quaternion shorter than 1e-12
    ("zero_quaternion"), or a scale whose exp overflows float32 ("scale_overflow").
    """
    with np.errstate(invalid="ignore", over="ignore"):  # bad rows are expected here: they are counted below
        return _decode(ply)


def valid_rows(ply: GaussianPly):
    """(keep mask (N,), dropped counts by reason) — the rows decode() keeps."""
    with np.errstate(invalid="ignore", over="ignore"):
        finite = (np.isfinite(ply.xyz).all(1) & np.isfinite(ply.f_dc).all(1)
                  & np.isfinite(ply.f_rest).all((1, 2)) & np.isfinite(ply.opacity)
                  & np.isfinite(ply.scale).all(1) & np.isfinite(ply.rot).all(1))
        zero_q = finite & (np.linalg.norm(ply.rot.astype(np.float64), axis=1) < 1e-12)
        overflow = finite & ~zero_q & ~(np.exp(ply.scale.astype(np.float64)) <= np.finfo(np.float32).max).all(1)
    dropped = {"non_finite": int(len(ply) - finite.sum()), "zero_quaternion": int(zero_q.sum()),
               "scale_overflow": int(overflow.sum())}
    return finite & ~zero_q & ~overflow, {k: v for k, v in dropped.items() if v}


def _decode(ply: GaussianPly) -> Gaussians:
    keep, dropped = valid_rows(ply)
    rot = ply.rot[keep].astype(np.float64)
    q = rot / np.linalg.norm(rot, axis=1, keepdims=True)
    opac = 1.0 / (1.0 + np.exp(-ply.opacity[keep].astype(np.float64)))
    sh = np.concatenate([ply.f_dc[keep][:, None, :], np.swapaxes(ply.f_rest[keep], 1, 2)], axis=1)  # (N, K, 3)
    return Gaussians(means=ply.xyz[keep].copy(), scales=np.exp(ply.scale[keep].astype(np.float64)).astype(np.float32),
                     quats=q.astype(np.float32), opacities=opac.astype(np.float32), sh=sh.astype(np.float32),
                     dropped=dropped)


def encode(g: Gaussians, extra: dict | None = None) -> GaussianPly:
    """Raw file values of decoded Gaussians: log scales, logit opacity (clamped to (1e-7, 1 - 1e-7))."""
    o = np.clip(g.opacities.astype(np.float64), 1e-7, 1 - 1e-7)
    return GaussianPly(xyz=g.means.astype(np.float32), f_dc=g.sh[:, 0].astype(np.float32),
                       f_rest=np.swapaxes(g.sh[:, 1:], 1, 2).astype(np.float32),
                       opacity=np.log(o / (1 - o)).astype(np.float32),
                       scale=np.log(np.maximum(g.scales.astype(np.float64), 1e-30)).astype(np.float32),
                       rot=g.quats.astype(np.float32), extra=dict(extra or {}))


def load(path) -> Gaussians:
    """read_ply + decode."""
    return decode(read_ply(path))


# --------------------------------------------------------------------------------------------------------------
# Spherical harmonics
# --------------------------------------------------------------------------------------------------------------

def sh_basis(dirs, degree: int) -> np.ndarray:
    """Real SH basis values (N, (degree+1)^2) at unit directions (N, 3), in the 3DGS ordering and signs."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0-3, got {degree}")
    d = np.asarray(dirs, np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    out = [np.full(len(d), SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2 * zz - xx - yy), SH_C2[3] * x * z,
                SH_C2[4] * (xx - yy)]
    if degree >= 3:
        out += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4 * zz - xx - yy),
                SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy), SH_C3[4] * x * (4 * zz - xx - yy),
                SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3 * yy)]
    return np.stack(out, axis=1)


def sh_to_rgb(sh, dirs, degree: int | None = None) -> np.ndarray:
    """Colour (N, 3) = max(0.5 + Σ_k basis_k(dir) sh_k, 0) for unit view directions (N, 3).

    ``dirs`` point from the camera to the Gaussian (normalise(mean - camera centre)), in the Gaussians' frame.
    ``degree`` below the data's own uses only the first coefficients.
    """
    sh = np.asarray(sh)
    degree = int(round(np.sqrt(sh.shape[1]))) - 1 if degree is None else degree
    K = num_sh_coefficients(degree)
    if K > sh.shape[1]:
        raise ValueError(f"SH degree {degree} needs {K} coefficients, the data has {sh.shape[1]}")
    B = sh_basis(dirs, degree)
    return np.maximum(np.einsum("nk,nkc->nc", B, sh[:, :K].astype(np.float64)) + 0.5, 0.0)
