"""``reader.read`` and ``reader.load`` (the fast paths: a float32 file read as one table, decoding without masks
when no row is dropped, the finiteness shortcut) give the same bits as a straightforward reference: the file's
vertex rows through numpy's structured dtype, each property copied on its own, and the activations written out
row-masked, as the reader did before it was made fast (bench/ply_load.py)."""

import numpy as np
import pytest

from scpainter_blender.core.splats import gaussians as splats
from scpainter_blender.core.splats import ply_format, reader
from tests.core.splats.splat_fixtures import inria_columns, random_ply, write_typed_ply


def reference_raw(path):
    """(xyz, f_dc, f_rest (N, 3, K-1), opacity, scale, rot) float32 of an INRIA PLY, one property at a time."""
    raw = open(path, "rb").read()
    fmt, elements, start = ply_format.parse_header(raw, path)
    order = "<" if fmt == "binary_little_endian" else ">"
    count, props = ply_format.element(elements, "vertex")
    data = np.frombuffer(raw, np.dtype([(p, order + t) for p, t in props]), count=count, offset=start)
    half = data.dtype["x"].str[1:] == "u2"

    def col(name):
        v = data[name].view(order + "f2") if half else data[name]
        with np.errstate(over="ignore"):
            return v.astype(np.float32)

    rest = sorted((p for p, _ in props if p.startswith("f_rest_")), key=lambda p: int(p[7:]))
    stack = lambda names: np.stack([col(n) for n in names], axis=1)  # noqa: E731
    return (stack("xyz"), stack([f"f_dc_{i}" for i in range(3)]),
            stack(rest).reshape(count, 3, len(rest) // 3) if rest else np.zeros((count, 3, 0), np.float32),
            col("opacity"), stack([f"scale_{i}" for i in range(3)]), stack([f"rot_{i}" for i in range(4)]))


def reference_decode(xyz, f_dc, f_rest, opacity, scale, rot):
    """The activations as documented in ``core.splats.gaussians``, bad rows masked out first."""
    with np.errstate(invalid="ignore", over="ignore"):
        finite = (np.isfinite(xyz).all(1) & np.isfinite(f_dc).all(1) & np.isfinite(f_rest).all((1, 2))
                  & np.isfinite(opacity) & np.isfinite(scale).all(1) & np.isfinite(rot).all(1))
        zero_q = finite & (np.linalg.norm(rot.astype(np.float64), axis=1) < 1e-12)
        overflow = finite & ~zero_q & ~(np.exp(scale.astype(np.float64)) <= np.finfo(np.float32).max).all(1)
    k = finite & ~zero_q & ~overflow
    q = rot[k].astype(np.float64)
    return {"means": xyz[k].copy(), "scales": np.exp(scale[k].astype(np.float64)).astype(np.float32),
            "quats": (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32),
            "opacities": (1.0 / (1.0 + np.exp(-opacity[k].astype(np.float64)))).astype(np.float32),
            "sh": np.concatenate([f_dc[k][:, None, :], np.swapaxes(f_rest[k], 1, 2)], axis=1).astype(np.float32),
            "dropped": {n: int(c.sum()) for n, c in (("non_finite", ~finite), ("zero_quaternion", zero_q),
                                                      ("scale_overflow", overflow)) if c.sum()}}


def same_bits(a, b, what):
    assert a.dtype == b.dtype and a.shape == b.shape, what
    assert a.tobytes() == b.tobytes(), what  # bit for bit, NaN payloads included


def with_bad_rows(ply):
    """Each kind of row ``decode`` drops, and a NaN among the SH coefficients (the finiteness shortcut's case)."""
    if ply.f_rest.shape[2]:
        ply.f_rest[3, 1, -1] = np.nan
    ply.f_dc[4, 2] = np.nan
    ply.xyz[5, 0] = np.inf
    ply.opacity[7] = -np.inf
    ply.rot[9] = 0.0
    ply.scale[11, 2] = 200.0  # exp overflows float32
    return ply


CASES = {
    # name: (ply, columns' PLY type, byte order, extra columns)
    "float32, clean": (lambda: random_ply(400, degree=3, seed=1, extras=False), "float", "<", "normals"),
    "float32, bad rows": (lambda: with_bad_rows(random_ply(400, degree=3, seed=2, extras=False)), "float", "<",
                          "normals"),
    "float32 big-endian, bad rows": (lambda: with_bad_rows(random_ply(400, degree=2, seed=3, extras=False)), "float",
                                     ">", "normals"),
    "float32 with a uchar label": (lambda: with_bad_rows(random_ply(400, degree=1, seed=4, extras=False)), "float",
                                   "<", "label"),
    "double": (lambda: with_bad_rows(random_ply(400, degree=3, seed=5, extras=False)), "double", "<", None),
    "half floats": (lambda: random_ply(400, degree=3, seed=6, extras=False), "ushort", "<", None),
    "degree 0": (lambda: with_bad_rows(random_ply(400, degree=0, seed=7, extras=False)), "float", "<", None),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("shuffled", [False, True])
def test_read_and_load_equal_the_reference(tmp_path, case, shuffled):
    make, ply_type, order, extra = CASES[case]
    ply = make()
    cast = (lambda v: v.astype(np.float16).view(np.uint16)) if ply_type == "ushort" else None
    columns = inria_columns(ply, ply_type, cast)
    N = len(ply)
    if extra == "normals":
        columns[3:3] = [(n, "float", np.full(N, 0.5, np.float32)) for n in ("nx", "ny", "nz")]
    elif extra == "label":
        columns.append(("label", "uchar", np.arange(N) % 200))
    if shuffled:  # properties in another file order: columns are no longer consecutive blocks
        columns = [columns[i] for i in np.random.default_rng(0).permutation(len(columns))]
    path = str(tmp_path / "g.ply")
    write_typed_ply(path, columns, byte_order=order)

    raw = reference_raw(path)
    got = reader.read(path)
    for name, ref in zip(("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"), raw):
        same_bits(getattr(got, name), ref, name)
    ref = reference_decode(*raw)
    assert ref["dropped"] or case in ("float32, clean", "half floats")  # the bad rows are there to be dropped
    g = reader.load(path)
    for name in ("means", "scales", "quats", "opacities", "sh"):
        same_bits(getattr(g, name), ref[name], name)
    assert g.dropped == ref["dropped"]


def test_decode_leaves_its_input_alone_and_owns_its_output():
    """Without a dropped row nothing is masked: the decoded arrays must still be new arrays, not the raw ones."""
    ply = random_ply(50, degree=1, seed=8, extras=False)
    before = [a.copy() for a in (ply.xyz, ply.f_dc, ply.f_rest)]
    g = splats.decode(ply)
    g.means[:] = 0.0
    g.sh[:] = 0.0
    for a, b in zip((ply.xyz, ply.f_dc, ply.f_rest), before):
        same_bits(a, b, "raw values")
