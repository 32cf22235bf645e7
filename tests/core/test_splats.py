"""core.splats: Gaussian PLY read/write (INRIA and TRELLIS/Amodal3R), decoding, SH, edge cases and a fuzz test."""

import os
import re
import time

import numpy as np
import pytest

from scpainter_blender.core import splats as SP


def random_ply(N=50, degree=0, seed=0, extras=True):
    rng = np.random.default_rng(seed)
    K1 = SP.num_sh_coefficients(degree) - 1
    extra = {}
    if extras:
        extra = {"nx": np.zeros(N, np.float32), "ny": np.zeros(N, np.float32), "nz": np.zeros(N, np.float32),
                 "label": rng.integers(0, 255, N).astype(np.uint8)}
    return SP.GaussianPly(
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
    filexyz = zup @ SP.TRELLIS_FILE_FROM_ZUP.T
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
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.shape == y.shape and x.dtype == y.dtype, k
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), k  # bit-exact, NaN included
    assert list(a.extra) == list(b.extra)
    for k in a.extra:
        assert a.extra[k].dtype == b.extra[k].dtype and np.array_equal(a.extra[k], b.extra[k]), k


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("order", ["<", ">"])
def test_write_read_round_trip_bit_exact(tmp_path, degree, order):
    ply = random_ply(degree=degree, seed=degree)
    ply.xyz[3, 1] = np.nan  # bad values survive the raw round trip too
    p = tmp_path / "g.ply"
    SP.write_ply(p, ply, byte_order=order)
    back = SP.read_ply(p)
    assert back.sh_degree == degree
    assert_raw_equal(ply, back)
    SP.write_ply(tmp_path / "again.ply", back, byte_order=order)
    assert (tmp_path / "again.ply").read_bytes() == p.read_bytes()
    assert not list(tmp_path.glob("*.tmp"))


def test_big_and_little_endian_decode_the_same(tmp_path):
    ply = random_ply(degree=3)
    SP.write_ply(tmp_path / "le.ply", ply, "<")
    SP.write_ply(tmp_path / "be.ply", ply, ">")
    a, b = SP.load(tmp_path / "le.ply"), SP.load(tmp_path / "be.ply")
    assert np.array_equal(a.means, b.means) and np.array_equal(a.sh, b.sh)


def test_decoding_activations():
    ply = random_ply(degree=2)
    g = SP.decode(ply)
    assert np.allclose(g.scales, np.exp(ply.scale), rtol=1e-6)
    assert np.allclose(g.opacities, 1 / (1 + np.exp(-ply.opacity)), rtol=1e-6)
    assert np.allclose(np.linalg.norm(g.quats, axis=1), 1.0, atol=1e-6)
    assert np.allclose(g.quats, ply.rot / np.linalg.norm(ply.rot, axis=1, keepdims=True), atol=1e-6)
    assert np.array_equal(g.sh[:, 0], ply.f_dc)
    assert np.array_equal(g.sh[:, 1:, 0], ply.f_rest[:, 0])  # channel-major f_rest: red's coefficients first
    assert np.array_equal(g.sh[:, 1:, 2], ply.f_rest[:, 2])


def test_encode_inverts_decode():
    ply = random_ply(degree=1, extras=False)
    back = SP.encode(SP.decode(ply))
    assert np.allclose(back.scale, ply.scale, atol=1e-5)
    assert np.allclose(back.opacity, ply.opacity, atol=1e-3)


def test_edge_cases_dropped_and_counted():
    ply = random_ply(N=8, degree=3, extras=False)
    ply.rot[0] = 0.0                      # zero quaternion
    ply.xyz[1, 2] = np.inf                # non-finite position
    ply.f_rest[2, 1, 5] = np.nan          # non-finite SH
    ply.scale[3] = [100.0, 0.0, 0.0]      # exp overflows float32
    ply.scale[4] = [-60.0, -60.0, -60.0]  # degenerate (tiny) but valid
    ply.opacity[5] = 1e4                  # saturated opacity: exactly 1, not NaN
    ply.opacity[6] = -1e4
    g = SP.decode(ply)
    assert g.dropped == {"non_finite": 2, "zero_quaternion": 1, "scale_overflow": 1}
    assert len(g) == 4
    for arr in (g.means, g.scales, g.quats, g.opacities, g.sh):
        assert np.all(np.isfinite(arr))
    assert g.opacities.max() == 1.0 and g.opacities.min() == 0.0
    assert g.scales.min() >= 0.0


def test_one_gaussian_and_empty(tmp_path):
    one = random_ply(N=1, degree=3, extras=False)
    SP.write_ply(tmp_path / "one.ply", one)
    assert len(SP.load(tmp_path / "one.ply")) == 1
    empty = random_ply(N=0, degree=0, extras=False)
    SP.write_ply(tmp_path / "empty.ply", empty)
    g = SP.load(tmp_path / "empty.ply")
    assert len(g) == 0 and g.sh.shape == (0, 1, 3)


def test_trellis_amodal3r_file(tmp_path):
    zup, arr = trellis_like_file(tmp_path / "amodal3r.ply")
    ply = SP.read_ply(tmp_path / "amodal3r.ply")
    assert ply.sh_degree == 0 and set(ply.extra) == {"nx", "ny", "nz"}
    g = SP.decode(ply)
    assert len(g) == 40 and g.dropped == {}
    back_to_zup = g.means.astype(np.float64) @ SP.TRELLIS_FILE_FROM_ZUP  # p = T^T p_file
    assert np.allclose(back_to_zup, zup, atol=1e-6)
    assert np.all(np.abs(back_to_zup) <= 0.5 + 1e-6)  # TRELLIS's unit cube


def test_missing_and_bad_properties_are_named(tmp_path):
    ply = random_ply(degree=0, extras=False)
    SP.write_ply(tmp_path / "ok.ply", ply)
    text = (tmp_path / "ok.ply").read_bytes()
    head, body = text.split(b"end_header\n", 1)
    # drop 'opacity' and 'rot_2' from the header (and their bytes, so the file is otherwise consistent)
    cut = head.replace(b"property float opacity\n", b"").replace(b"property float rot_2\n", b"")
    (tmp_path / "missing.ply").write_bytes(cut + b"end_header\n" + body)
    with pytest.raises(SP.SplatsError, match=r"missing.ply.*missing required properties \['opacity', 'rot_2'\]"):
        SP.read_ply(tmp_path / "missing.ply")
    bad_rest = head.replace(b"property float opacity\n", b"property float f_rest_0\nproperty float opacity\n")
    (tmp_path / "rest.ply").write_bytes(bad_rest + b"end_header\n" + body + b"\0" * 4 * 50)
    with pytest.raises(SP.SplatsError, match="1 f_rest properties"):
        SP.read_ply(tmp_path / "rest.ply")
    ascii_ = head.replace(b"binary_little_endian", b"ascii")
    (tmp_path / "ascii.ply").write_bytes(ascii_ + b"end_header\n" + body)
    with pytest.raises(SP.SplatsError, match="'ascii' is not supported"):
        SP.read_ply(tmp_path / "ascii.ply")
    (tmp_path / "short.ply").write_bytes(text[: len(text) - 7])
    with pytest.raises(SP.SplatsError, match="truncated.*50 Gaussians"):
        SP.read_ply(tmp_path / "short.ply")
    with pytest.raises(SP.SplatsError, match="not found"):
        SP.read_ply(tmp_path / "nope.ply")


def test_extra_properties_are_ignored(tmp_path):
    ply = random_ply(degree=1)
    SP.write_ply(tmp_path / "x.ply", ply)
    g = SP.load(tmp_path / "x.ply")
    plain = SP.decode(SP.GaussianPly(ply.xyz, ply.f_dc, ply.f_rest, ply.opacity, ply.scale, ply.rot))
    assert np.array_equal(g.means, plain.means) and np.array_equal(g.sh, plain.sh)


# -- spherical harmonics -----------------------------------------------------------------------------------------

def fibonacci_sphere(n):
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)


def test_sh_basis_is_orthonormal():
    d = fibonacci_sphere(200_000)
    B = SP.sh_basis(d, 3)
    gram = 4 * np.pi * (B.T @ B) / len(d)  # ∫ Y_i Y_j dΩ
    assert np.abs(gram - np.eye(16)).max() < 1e-3


def test_sh_to_rgb():
    rng = np.random.default_rng(0)
    sh = rng.normal(0, 0.3, (100, 16, 3))
    d = fibonacci_sphere(100)
    dc_only = SP.sh_to_rgb(sh, d, degree=0)
    assert np.allclose(dc_only, np.maximum(0.5 + SP.SH_C0 * sh[:, 0], 0))
    full = SP.sh_to_rgb(sh, d)
    assert np.allclose(full, np.maximum(0.5 + np.einsum("nk,nkc->nc", SP.sh_basis(d, 3), sh), 0))
    assert full.min() >= 0.0
    # degree 1 along +z: the basis is (C0, -C1·y, C1·z, -C1·x) = (C0, 0, C1, 0)
    one = np.zeros((1, 4, 3))
    one[0, 2] = 1.0
    assert np.allclose(SP.sh_to_rgb(one, [[0, 0, 1.0]]), 0.5 + SP.SH_C1)
    with pytest.raises(ValueError):
        SP.sh_to_rgb(one, [[0, 0, 1.0]], degree=2)


# -- fuzzing -----------------------------------------------------------------------------------------------------

def _corrupt(data: bytes, rng) -> bytes:
    head_end = data.find(b"end_header") + 11
    kind = rng.integers(0, 10)
    b = bytearray(data)
    if kind == 0:                                   # truncation anywhere
        return bytes(b[: rng.integers(0, len(b))])
    if kind == 1:                                   # flipped bytes in the header
        for _ in range(rng.integers(1, 4)):
            i = rng.integers(0, head_end)
            b[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(b)
    if kind == 2:                                   # wrong vertex count
        n = int(rng.choice([0, 1, 2, 10**6, 10**15, -5, int(rng.integers(0, 200))]))
        return re.sub(rb"element vertex \d+", b"element vertex %d" % n, data)
    if kind == 3:                                   # garbage inserted
        i = rng.integers(0, len(b))
        return bytes(b[:i]) + rng.bytes(int(rng.integers(1, 64))) + bytes(b[i:])
    if kind == 4:                                   # garbage over the body (NaNs, infs, anything)
        i = rng.integers(head_end, len(b))
        n = int(rng.integers(1, 256))
        b[i:i + n] = rng.bytes(len(b[i:i + n]))
        return bytes(b)
    if kind == 5:                                   # a header line deleted or duplicated
        lines = data[:head_end].split(b"\n")
        j = int(rng.integers(1, len(lines) - 1))
        lines.insert(j, lines[j]) if rng.random() < 0.5 else lines.pop(j)
        return b"\n".join(lines) + data[head_end:]
    if kind == 6:                                   # types and formats swapped
        swaps = [(b"float", b"double"), (b"float", b"uchar"), (b"binary_little_endian", b"binary_big_endian"),
                 (b"binary_little_endian", b"ascii"), (b"vertex", b"face"), (b"property", b"propertx")]
        a, c = swaps[int(rng.integers(0, len(swaps)))]
        return data.replace(a, c, int(rng.integers(1, 3)))
    if kind == 7:                                   # pure noise, sometimes with a PLY magic
        noise = rng.bytes(int(rng.integers(0, 2000)))
        return (b"ply\n" + noise) if rng.random() < 0.5 else noise
    if kind == 8:                                   # a list property or an element before the vertices
        return data.replace(b"element vertex", b"element junk 3\nproperty list uchar int idx\nelement vertex", 1)
    return data.replace(b"end_header\n", b"end_header", 1)  # header glued to the body



def test_fuzz_corruptions_end_in_error_or_valid_asset(tmp_path):
    sources = []
    trellis_like_file(tmp_path / "trellis.ply", N=60)
    sources.append((tmp_path / "trellis.ply").read_bytes())
    SP.write_ply(tmp_path / "inria.ply", random_ply(N=60, degree=3))
    sources.append((tmp_path / "inria.ply").read_bytes())
    SP.write_ply(tmp_path / "be.ply", random_ply(N=30, degree=1), byte_order=">")
    sources.append((tmp_path / "be.ply").read_bytes())
    rng = np.random.default_rng(12345)
    outcomes = {"error": 0, "valid": 0}
    slowest = 0.0
    target = tmp_path / "fuzz.ply"
    for case in range(1200):
        target.write_bytes(_corrupt(sources[case % len(sources)], rng))
        t = time.perf_counter()
        try:
            g = SP.load(target)
        except SP.SplatsError as e:
            assert "fuzz.ply" in str(e)
            outcomes["error"] += 1
        else:
            for arr in (g.means, g.scales, g.quats, g.opacities, g.sh):
                assert np.all(np.isfinite(arr)), case
            assert np.allclose(np.linalg.norm(g.quats, axis=1), 1, atol=1e-5) if len(g) else True
            outcomes["valid"] += 1
        slowest = max(slowest, time.perf_counter() - t)
    assert outcomes["error"] > 300 and outcomes["valid"] > 100, outcomes
    assert slowest < 1.0, slowest
    print(f"fuzz: {outcomes}, slowest case {slowest * 1e3:.1f} ms")
    os.remove(target)
