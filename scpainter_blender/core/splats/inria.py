"""The INRIA 3DGS PLY layout, both ways: its vertex properties into a ``GaussianPly`` (float, double or half
floats; TRELLIS/Amodal3R files are this layout too), and ``write_ply``, which writes it bit-exact to what is read.

The layout (graphdeco-inria/gaussian-splatting ``scene/gaussian_model.py``, ``save_ply``): one ``vertex`` element
with the properties ``x y z [nx ny nz] f_dc_0..2 [f_rest_0..M-1] opacity scale_0..2 rot_0..3``, binary little- or
big-endian, holding the raw values ``core.splats.gaussians.GaussianPly`` describes (logit opacity, log scales,
quaternion (w, x, y, z), f_rest channel-major with M = 0, 9, 24 or 45).

Property types: ``float`` and ``double`` are read as float32 ("inria"). A file whose every Gaussian property
(x y z f_dc_* opacity scale_* rot_* f_rest_*) is ``ushort``/``uint16`` is a half-float export: the 16 bits are
IEEE half floats in the file's byte order ("inria_half"). Any other integer type among them (or a mix of ushort
and float) is refused naming the property: integers there have no agreed meaning. Other properties (normals,
labels...) keep their own type in ``GaussianPly.extra`` and are written back in it.

No bpy, no torch: numpy only.
"""

from __future__ import annotations

import os

import numpy as np

from .. import outputs
from . import ply_format
from .gaussians import GaussianPly, SplatsError, num_sh_coefficients

#: The vertex properties every Gaussian PLY of this layout has.
REQUIRED = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
            "rot_0", "rot_1", "rot_2", "rot_3")


def _storage(data, keys, path) -> str:
    """"inria" when every key is float/double, "inria_half" when every key is ushort; SplatsError otherwise."""
    kinds = {k: data.dtype[k] for k in keys}
    nonfloat = [k for k in keys if kinds[k].kind != "f"]
    if not nonfloat:
        return "inria"
    if len(nonfloat) == len(keys) and all(kinds[k].str[1:] == "u2" for k in keys):
        return "inria_half"
    k = nonfloat[0]
    more = f" (and {len(nonfloat) - 1} more)" if len(nonfloat) > 1 else ""
    if all(kinds[n].str[1:] == "u2" for n in nonfloat):
        raise SplatsError(path, f"property {k!r}{more} is stored as {ply_format.type_name(kinds[k])} while others "
                                "are float: a half-float export stores every Gaussian property as ushort, a mix is "
                                "ambiguous; re-export the file as float32", k)
    raise SplatsError(path, f"property {k!r}{more} is stored as {ply_format.type_name(kinds[k])}: Gaussian "
                            "properties must be float or double (integers have no agreed scale); re-export the file "
                            "as float32", k)


def from_vertex(data, names, path) -> GaussianPly:
    """The raw values of a vertex element read as a structured array ``data`` with property ``names`` in file
    order; SplatsError naming the property for a missing, misnumbered or wrongly typed one."""
    missing = [k for k in REQUIRED if k not in names]
    if missing:
        raise SplatsError(path, f"missing required properties {missing}", missing[0])
    rest = sorted((n for n in names if n.startswith("f_rest_")), key=lambda n: int(n[7:]) if n[7:].isdigit() else -1)
    if rest and [n[7:] for n in rest] != [str(i) for i in range(len(rest))]:
        raise SplatsError(path, f"f_rest properties must be numbered 0..{len(rest) - 1} without gaps", rest[0])
    valid = {3 * (num_sh_coefficients(d) - 1): d for d in range(4)}
    if len(rest) not in valid:
        raise SplatsError(path, f"{len(rest)} f_rest properties: expected 0, 9, 24 or 45 (SH degree 0-3)",
                          rest[-1])
    used = list(REQUIRED) + rest
    storage = _storage(data, used, path)

    def column(k):
        if storage == "inria_half":  # the same bits as IEEE half floats, in the file's byte order
            return data[k].view(data.dtype[k].str[0] + "f2")
        return data[k]

    table = _float32_table(data)

    def cols(keys):  # doubles beyond float32's range become inf here, and are dropped on decoding
        if table is not None:
            return _columns(table, [names.index(k) for k in keys])
        out = np.empty((len(data), len(keys)), np.float32)
        with np.errstate(invalid="ignore", over="ignore"):
            for i, k in enumerate(keys):
                out[:, i] = column(k)
        return out

    K1 = len(rest) // 3
    used_set = set(used)
    return GaussianPly(
        xyz=cols(["x", "y", "z"]), f_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        f_rest=cols(rest).reshape(len(data), 3, K1), opacity=cols(["opacity"])[:, 0],
        scale=cols(["scale_0", "scale_1", "scale_2"]), rot=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        extra={n: data[n].astype(data.dtype[n].newbyteorder("=")) for n in names if n not in used_set},
        format=storage, properties=tuple(names))


def _float32_table(data):
    """The vertex rows as an (N, P) float32 view (file byte order) when every property is a float32 (the usual
    INRIA file), else None. Columns then copy as blocks of rows instead of one strided property at a time: a
    1 M-Gaussian degree-3 file reads ~5x faster (bench/ply_load.py); the values are the same bits either way."""
    types = {data.dtype[k].str for k in data.dtype.names}
    if len(types) != 1 or next(iter(types))[1:] != "f4" or data.dtype.itemsize != 4 * len(data.dtype.names) \
            or not data.flags.c_contiguous:
        return None
    return data.view(next(iter(types))).reshape(len(data), len(data.dtype.names))


def _columns(table, index) -> np.ndarray:
    """Native float32 (N, len(index)) copy of ``table``'s columns ``index`` (a slice when they are consecutive)."""
    first = index[0] if index else 0
    if index == list(range(first, first + len(index))):
        return np.array(table[:, first:first + len(index)], dtype=np.float32)
    return np.array(table[:, index], dtype=np.float32)


def write_names(ply: GaussianPly) -> list:
    """The vertex properties ``write_ply`` writes for ``ply``, in its order: x y z, normals if present among the
    extras, f_dc, f_rest, opacity, scale, rot, the other extras."""
    normals = [n for n in ("nx", "ny", "nz") if n in ply.extra]
    K1 = ply.f_rest.shape[2]
    return (["x", "y", "z"] + normals + [f"f_dc_{i}" for i in range(3)] + [f"f_rest_{i}" for i in range(3 * K1)]
            + ["opacity"] + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
            + [n for n in ply.extra if n not in normals])


def write_ply(path, ply: GaussianPly, byte_order: str = "<", comment: str | None = None) -> None:
    """Write ``ply`` in the INRIA layout (float32; extras in their own types), atomically (temp file, rename).

    Property order: ``write_names``. ``byte_order`` "<" (little-endian) or ">"; ``comment`` one header line
    (characters outside printable ASCII become "?").
    """
    if byte_order not in "<>":
        raise ValueError("byte_order must be '<' or '>'")
    N = len(ply)
    K1 = ply.f_rest.shape[2]
    fields = [(n, ply.extra[n].dtype.str[1:] if n in ply.extra else "f4") for n in write_names(ply)]
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
    for n in ply.extra:
        arr[n] = ply.extra[n]
    header = ["ply", f"format binary_{'little' if byte_order == '<' else 'big'}_endian 1.0"]
    if comment:  # one line of printable ASCII: a newline in it would write header lines of its own
        header.append("comment " + "".join(ch if " " <= ch <= "~" else "?" for ch in comment))
    header.append(f"element vertex {N}")
    header += [f"property {ply_format.PLY_TYPE[t]} {n}" for n, t in fields]
    header.append("end_header")
    with outputs.atomic_write(os.fspath(path)) as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(arr.tobytes())
