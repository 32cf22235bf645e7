"""core.splats.compressed: SuperSplat compressed PLY against an independent encoder (tests/core/splats/splat_fixtures.py)
and SuperSplat's own export, and antimatter15 .splat (byte conventions, round trip, sizes)."""

import time

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
from tests_support import realdata
from scpainter_blender.core.geometry import cameras as C
from scpainter_blender.core.splats import gaussians as splats, compressed as splats_compressed, reader as splats_io
from scpainter_blender.core.splats.sh import SH_C0


# -- SuperSplat compressed PLY -------------------------------------------------------------------------------------

COMPRESSED = "compressed/olgelta_longheadpiece_scene.compressed.ply"


@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("chunk_colors", [True, False])
def test_compressed_decode_inverts_an_independent_encoder(tmp_path, degree, chunk_colors):
    """decode(encode(x)) = x within half a quantisation step, for 3 chunks (the last one partial)."""
    src = F.random_gaussians(700, degree, seed=degree + 10 * chunk_colors)
    p = tmp_path / "x.compressed.ply"
    table = F.write_compressed(p, src, chunk_colors).astype(np.float64)
    ply = splats_io.read(p)
    assert ply.format == "supersplat_compressed" and len(ply) == 700 and ply.sh_degree == degree
    assert splats_io.read_ply(p).format == "supersplat_compressed"  # read_ply dispatches too
    ci = np.arange(700) // 256
    for i, bits in enumerate((11, 10, 11)):
        step = (table[ci, 3 + i] - table[ci, i]) / (2 ** bits - 1)
        assert np.all(np.abs(ply.xyz[:, i] - src.xyz[:, i]) <= step / 2 + 1e-6), i
        sstep = (table[ci, 9 + i] - table[ci, 6 + i]) / (2 ** bits - 1)
        assert np.all(np.abs(ply.scale[:, i] - src.scale[:, i]) <= sstep / 2 + 1e-6), i
    colour = 0.5 + SH_C0 * src.f_dc.astype(np.float64)
    got = 0.5 + SH_C0 * ply.f_dc.astype(np.float64)
    if chunk_colors:
        cstep = (table[ci, 15:18] - table[ci, 12:15]) / 255
        assert np.all(np.abs(got - colour) <= cstep / 2 + 1e-6)
    else:  # colours are stored as they are, clipped to [0, 1]
        assert np.all(np.abs(got - np.clip(colour, 0, 1)) <= 0.5 / 255 + 1e-6)
    alpha = 1 / (1 + np.exp(-src.opacity.astype(np.float64)))
    assert np.all(np.abs(1 / (1 + np.exp(-ply.opacity.astype(np.float64))) - alpha) <= 0.5 / 255 + 1e-6)
    assert np.all(np.isfinite(ply.opacity))
    assert F.same_rotation_error(ply.rot.astype(np.float64), src.rot.astype(np.float64)) < 2e-3
    assert np.abs(np.linalg.norm(ply.rot, axis=1) - 1).max() < 1e-5
    if degree:
        v, d = src.f_rest.astype(np.float64), ply.f_rest.astype(np.float64)
        inner = np.abs(v) < 4 - 1 / 32
        assert np.all(np.abs(d - v)[inner] <= 1 / 64 + 1e-6)  # the middle of a 1/32 bucket
        assert np.all(d[v >= 4 - 1 / 32] == 4.0) and np.all(d[v <= -4 + 1 / 32] == -4.0)
    g = splats_io.load(p)
    assert len(g) == 700 and g.dropped == {}


def test_compressed_quaternion_largest_component_and_sign(tmp_path):
    """Each of the four components largest, with either sign: the 2-bit index says which, the decoded quaternion
    is the same rotation with that component positive (the writer flips q to -q)."""
    rng = np.random.default_rng(3)
    qs, cases = [], []
    for largest in range(4):
        for sign in (1.0, -1.0):
            q = rng.uniform(-0.35, 0.35, 4)
            q[largest] = sign * 0.8
            qs.append(q / np.linalg.norm(q))
            cases.append((largest, sign))
    qs = np.array(qs)
    words = F.pack_rotation(qs)
    assert [int(w) >> 30 for w in words] == [c[0] for c in cases]
    src = F.random_gaussians(len(qs), 0, seed=4)
    src.rot = qs.astype(np.float32)
    F.write_compressed(tmp_path / "q.ply", src)
    got = splats_io.read(tmp_path / "q.ply").rot.astype(np.float64)
    for (largest, sign), q, d in zip(cases, qs, got):
        assert d[largest] > 0
        assert np.abs(d - sign * q).max() < 2e-3, (largest, sign)


def test_compressed_rotation_word_by_hand():
    """A 120° turn about +y, q = (w, x, y, z) = (0.5, 0, 0.866, 0): y (index 2) is largest; w, x, z are stored in
    that order as floor((q·√2/2 + 0.5)·1023 + 0.5) = 873, 512, 512."""
    word = (2 << 30) | (873 << 20) | (512 << 10) | 512
    q = splats_compressed.decode_packed_rotation(np.array([word], np.uint32))[0]
    w, x, z = (np.array([873, 512, 512]) / 1023 - 0.5) * np.sqrt(2)
    assert np.allclose(q, [w, x, np.sqrt(1 - w * w - x * x - z * z), z], atol=1e-12)
    assert np.allclose(q, [0.5, 0, np.sqrt(0.75), 0], atol=1.5e-3)
    R = C.quaternion_to_rotation(q[None] / np.linalg.norm(q))[0]
    assert np.allclose(R @ [1, 0, 0], [np.cos(np.radians(120)), 0, -np.sin(np.radians(120))], atol=3e-3)


def test_compressed_sh_bytes(tmp_path):
    """SH byte k decodes to the middle of its bucket, ((k + 0.5)/256 - 0.5)·8, with 0 and 255 at -4 and +4."""
    src = F.random_gaussians(5, 1, seed=5)
    F.write_compressed(tmp_path / "sh.ply", src)
    raw = (tmp_path / "sh.ply").read_bytes()
    sh_bytes = np.array([[0, 1, 128, 254, 255, 127, 64, 192, 200]] * 5, np.uint8)
    (tmp_path / "sh.ply").write_bytes(raw[: len(raw) - sh_bytes.size] + sh_bytes.tobytes())
    got = splats_io.read(tmp_path / "sh.ply").f_rest.reshape(5, 9)[0]
    mid = ((np.array([0, 1, 128, 254, 255, 127, 64, 192, 200]) + 0.5) / 256 - 0.5) * 8
    mid[0], mid[4] = -4.0, 4.0
    assert np.allclose(got, mid, atol=1e-6)
    assert np.isclose(got[1], -3.953125) and np.isclose(got[2], 0.015625)


def test_compressed_errors_name_the_file_and_problem(tmp_path):
    src = F.random_gaussians(300, 1, seed=6)
    p = tmp_path / "good.ply"
    F.write_compressed(p, src)
    data = p.read_bytes()
    cases = [("cut.ply", data[:-100], r"cut\.ply.*truncated.*300 SH rows"),
             ("cut2.ply", data[: len(data) // 2], r"cut2\.ply.*truncated.*300 Gaussians"),
             ("chunks.ply", data.replace(b"element chunk 2", b"element chunk 3"),
              r"chunks\.ply.*300 Gaussians need 2 chunks.*has 3"),
             ("nochunk.ply", data.replace(b"element chunk", b"element chunx"), "no 'chunk' element"),
             ("packed.ply", data.replace(b"uint packed_scale", b"uint packed_scalf"), r"missing \['packed_scale'\]"),
             ("shtype.ply", data.replace(b"uchar f_rest_3", b"char f_rest_3"),
              "sh property 'f_rest_3' is char.*expected uchar")]
    for name, raw, match in cases:
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(splats.SplatsError, match=match):
            splats_io.read(tmp_path / name)



def test_compressed_words_declared_int_read_as_their_bits(tmp_path):
    """``packed_*`` declared ``int`` instead of ``uint`` (an encoder's slip): the same 32 bits, read bit-equal,
    including words with the top bit set (a negative int32: rotation words whose largest component is w or z)."""
    src = F.random_gaussians(300, 1, seed=7)
    p = tmp_path / "uint.ply"
    F.write_compressed(p, src)
    data = p.read_bytes()
    end = data.index(b"end_header\n") + 11
    header = data[:end].decode().splitlines()
    table = int(next(x for x in header if x.startswith("element chunk")).split()[2]) * 4 * sum(
        x.startswith("property float") for x in header)
    words = np.frombuffer(data, "<u4", 300 * 4, end + table)
    assert (words >= 1 << 31).any()   # the case that matters is present
    (tmp_path / "int.ply").write_bytes(data[:end].replace(b"property uint packed_", b"property int packed_")
                                       + data[end:])
    a, b = splats_io.read(p), splats_io.read(tmp_path / "int.ply")
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k

def _chunk_table(path):
    """The chunk element of a compressed PLY, parsed here independently of core.splats.gaussians."""
    raw = open(path, "rb").read(1 << 16)
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    lines = raw[:end].decode("ascii").splitlines()
    count = next(int(line.split()[2]) for line in lines if line.startswith("element chunk"))
    first = lines.index(f"element chunk {count}")
    names = []
    for line in lines[first + 1:]:
        if not line.startswith("property float"):
            break
        names.append(line.split()[2])
    table = np.fromfile(path, dtype=[(n, "<f4") for n in names], count=count, offset=end)
    return {n: table[n].astype(np.float64) for n in names}


def test_real_supersplat_compressed_file():
    """SuperSplat 1.12.2's own export (220,315 splats, 861 chunks, chunk colours, SH 0)."""
    path = realdata(COMPRESSED)
    times = []
    for _ in range(3):
        t = time.process_time()   # CPU: the reader's cost, not the machine's load
        ply = splats_io.read(path)
        times.append(time.process_time() - t)
    print(f"compressed read + unpack: best {min(times) * 1e3:.0f} ms of {[round(x * 1e3) for x in times]}")
    assert min(times) < 1.0
    N = 220_315
    assert len(ply) == N and ply.format == "supersplat_compressed" and ply.sh_degree == 0
    for a in (ply.xyz, ply.f_dc, ply.opacity, ply.scale, ply.rot):
        assert np.all(np.isfinite(a))
    assert np.abs(np.linalg.norm(ply.rot.astype(np.float64), axis=1) - 1).max() < 1e-5
    g = splats.decode(ply)
    assert len(g) == N and g.dropped == {}
    assert g.opacities.min() >= 0 and g.opacities.max() <= 1

    table = _chunk_table(path)
    assert len(table["min_x"]) == 861
    ci = np.arange(N) // 256
    colour = 0.5 + SH_C0 * ply.f_dc.astype(np.float64)
    for i, a in enumerate("xyz"):
        lo, hi = table[f"min_{a}"][ci], table[f"max_{a}"][ci]
        assert np.all((ply.xyz[:, i] >= lo - 1e-6) & (ply.xyz[:, i] <= hi + 1e-6)), a
        slo, shi = table[f"min_scale_{a}"][ci], table[f"max_scale_{a}"][ci]
        assert np.all((ply.scale[:, i] >= slo - 1e-5) & (ply.scale[:, i] <= shi + 1e-5)), a
        assert np.all((g.scales[:, i] >= np.exp(slo) * (1 - 1e-5)) & (g.scales[:, i] <= np.exp(shi) * (1 + 1e-5)))
    for i, c in enumerate("rgb"):
        lo, hi = table[f"min_{c}"][ci], table[f"max_{c}"][ci]
        assert np.all((colour[:, i] >= lo - 1e-6) & (colour[:, i] <= hi + 1e-6)), c

    # The writer sets each chunk's box from its own members, so in every full chunk some splat sits at the box's
    # minimum (all bits 0) and some at its maximum (all bits 1), field by field. Any wrong bit width, field order or
    # byte order breaks this exactly; the right decoding meets it to float precision.
    full = N // 256
    def per_chunk(v):
        return v[: full * 256].reshape(full, 256)
    for i, a in enumerate("xyz"):
        assert np.abs(per_chunk(ply.xyz[:, i]).min(1) - table[f"min_{a}"][:full]).max() < 1e-6, a
        assert np.abs(per_chunk(ply.xyz[:, i]).max(1) - table[f"max_{a}"][:full]).max() < 1e-6, a
        assert np.abs(per_chunk(ply.scale[:, i]).min(1) - table[f"min_scale_{a}"][:full]).max() < 1e-5, a
        assert np.abs(per_chunk(ply.scale[:, i]).max(1) - table[f"max_scale_{a}"][:full]).max() < 1e-5, a
    for i, c in enumerate("rgb"):
        assert np.abs(per_chunk(colour[:, i]).min(1) - table[f"min_{c}"][:full]).max() < 1e-6, c
        assert np.abs(per_chunk(colour[:, i]).max(1) - table[f"max_{c}"][:full]).max() < 1e-6, c

    # Splats are stored in Morton order: file neighbours in a chunk are space neighbours and look alike.
    same = (np.arange(N - 1) // 256) == (np.arange(1, N) // 256)
    perm = np.random.default_rng(0).permutation(N)
    step = np.linalg.norm(np.diff(ply.xyz, axis=0), axis=1)[same]
    jump = np.linalg.norm(ply.xyz[perm] - ply.xyz, axis=1)
    assert np.median(step) < 0.05 * np.median(jump)
    dcol = np.abs(np.diff(colour, axis=0)).sum(1)[same]
    assert np.median(dcol) < 0.5 * np.median(np.abs(colour[perm] - colour).sum(1))

    # Orientation: a flat splat's thin axis is its surface normal, which the positions of its neighbours also
    # give (their least principal direction). This ties the quaternion's component order (w first) and the
    # scale axes to the geometry; reading the same bits as (x, y, z, w) would not align.
    X = g.means.astype(np.float64)
    order = np.argsort(X[:, 0])
    xs = X[order, 0]
    srt = np.sort(g.scales, axis=1)
    flat = np.flatnonzero((srt[:, 0] < 0.2 * srt[:, 1]) & (g.opacities > 0.5))
    picks = np.random.default_rng(1).choice(flat, 200, replace=False)
    normals, nn = [], []
    for i in picks:
        lo, hi = np.searchsorted(xs, [X[i, 0] - 0.05, X[i, 0] + 0.05])
        cand = X[order[lo:hi]]
        d = np.linalg.norm(cand - X[i], axis=1)
        near = cand[np.argsort(d)[:25]]
        nn.append(np.sort(d)[1])
        P = near - near.mean(0)
        normals.append(np.linalg.eigh(P.T @ P)[1][:, 0])
    normals = np.array(normals)

    def alignment(quats):
        R = C.quaternion_to_rotation(quats[picks].astype(np.float64))
        thin = np.argmin(g.scales[picks], axis=1)
        axis = R[np.arange(len(picks)), :, thin]
        return float(np.median(np.abs((axis * normals).sum(1))))

    right, wlast = alignment(g.quats), alignment(g.quats[:, [3, 0, 1, 2]])
    print(f"thin axis vs neighbour-plane normal, median |cos|: {right:.3f} (w first), {wlast:.3f} (w last)")
    assert right > 0.7 and wlast < right - 0.1
    # Sizes are exp(log scale): the largest σ is of the order of the spacing between neighbours.
    ratio = np.median(g.scales[picks].max(1)) / np.median(nn)
    assert 0.5 < ratio < 50, ratio


def test_real_compressed_file_truncated(tmp_path):
    data = open(realdata(COMPRESSED), "rb").read()
    (tmp_path / "cut.compressed.ply").write_bytes(data[: len(data) - 1000])
    with pytest.raises(splats.SplatsError, match=r"cut\.compressed\.ply: truncated.*220315 Gaussians"):
        splats_io.load(tmp_path / "cut.compressed.ply")


# -- antimatter15 .splat -------------------------------------------------------------------------------------------

def test_splat_byte_conventions(tmp_path):
    rec = np.zeros(3, splats_compressed.SPLAT_RECORD)
    rec["xyz"] = [[1, 2, 3], [-1, 0, 0.5], [0, 0, 0]]
    rec["scale"] = [[0.1, 0.2, 0.4], [1, 1, 1], [0.01, 0.02, 0.03]]
    rec["rgba"] = [[255, 0, 128, 255], [10, 20, 30, 0], [128, 128, 128, 128]]
    rec["rot"] = [[192, 128, 128, 192], [255, 128, 128, 128], [128, 128, 128, 128]]
    (tmp_path / "t.splat").write_bytes(rec.tobytes())
    ply = splats_io.read(tmp_path / "t.splat")
    assert ply.format == "splat" and len(ply) == 3 and ply.sh_degree == 0
    assert np.array_equal(ply.xyz, rec["xyz"])
    assert np.allclose(ply.scale, np.log(rec["scale"].astype(np.float32)), atol=1e-6)
    assert np.allclose(ply.f_dc[0], [(1 - 0.5) / SH_C0, -0.5 / SH_C0, (128 / 255 - 0.5) / SH_C0])
    assert np.allclose(ply.rot[0], [0.5, 0, 0, 0.5]) and np.allclose(ply.rot[1], [127 / 128, 0, 0, 0])
    a = 1 - 1e-6
    assert np.isclose(ply.opacity[0], np.log(a / (1 - a)), rtol=1e-5)  # 255 stays finite
    assert np.isclose(ply.opacity[1], -np.log(a / (1 - a)), rtol=1e-5)  # and so does 0
    g = splats_io.load(tmp_path / "t.splat")
    assert g.dropped == {"zero_quaternion": 1} and len(g) == 2  # bytes 128,128,128,128 are a zero quaternion
    assert np.allclose(g.quats[0], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-6)
    assert np.allclose(g.base_colors()[0], [1.0, 0.0, 128 / 255], atol=1e-6)


def test_splat_write_read_round_trip(tmp_path):
    g = splats.decode(F.random_gaussians(400, 0, seed=8))
    splats_compressed.write_splat(tmp_path / "g.splat", g)
    assert (tmp_path / "g.splat").stat().st_size == 32 * 400
    back = splats_io.load(tmp_path / "g.splat")
    assert len(back) == 400 and back.dropped == {}
    assert np.array_equal(back.means, g.means)
    assert np.allclose(back.scales, g.scales, rtol=1e-6)
    assert np.all(np.abs(back.opacities - g.opacities) <= 0.5 / 255 + 1e-6)
    expected = np.clip(g.base_colors(), 0, 1)
    assert np.all(np.abs(back.base_colors() - expected) <= 0.5 / 255 + 1e-6)
    assert F.same_rotation_error(back.quats.astype(np.float64), g.quats.astype(np.float64)) < 0.02
    # a raw GaussianPly is accepted too (decoded first)
    splats_compressed.write_splat(tmp_path / "raw.splat", F.random_gaussians(400, 0, seed=8))
    assert (tmp_path / "raw.splat").read_bytes() == (tmp_path / "g.splat").read_bytes()


def test_splat_size_must_be_a_multiple_of_32(tmp_path):
    splats_compressed.write_splat(tmp_path / "ok.splat", splats.decode(F.random_gaussians(3, 0, seed=9)))
    data = (tmp_path / "ok.splat").read_bytes()
    (tmp_path / "bad.splat").write_bytes(data[:-5])
    with pytest.raises(splats.SplatsError, match=r"bad\.splat.*91 bytes, not a multiple of 32"):
        splats_io.read(tmp_path / "bad.splat")
    (tmp_path / "empty.splat").write_bytes(b"")
    with pytest.raises(splats.SplatsError, match=r"empty\.splat.*empty"):
        splats_io.load(tmp_path / "empty.splat")
