"""core.splats: Gaussian files (INRIA and TRELLIS/Amodal3R PLY, half-float PLY, SuperSplat compressed PLY, .splat):
read/write, decoding, SH, TRELLIS detection, edge cases, real files and a fuzz test."""

import os
import re
import time

import numpy as np
import pytest

import splat_fixtures as F
from tests_support import realdata
from scpainter_blender.core import cameras as C
from scpainter_blender.core import shapes
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
    filexyz = zup @ SP.ZUP_TO_TRELLIS_FILE.T
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
    back_to_zup = g.means.astype(np.float64) @ SP.ZUP_TO_TRELLIS_FILE  # p = T^T p_file
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


# -- the header: where it ends, its limits, what is refused (issue 14) ---------------------------------------------

def _with_header_lines(data: bytes, before_elements=(), before_end=()) -> bytes:
    """``data`` (a PLY written by write_ply) with extra header lines after the format line and before end_header."""
    head, body = data.split(b"\nend_header\n", 1)
    lines = head.split(b"\n")
    lines[2:2] = list(before_elements)
    return b"\n".join(lines + list(before_end)) + b"\nend_header\n" + body


@pytest.mark.parametrize("where", ["before_elements", "before_end"])
@pytest.mark.parametrize("line", [b"comment made by the end_header tool", b"obj_info end_header", b"comment end_header",
                                  b"comment \xe2\x9c\x93 caf\xc3\xa9 end_header"])
def test_comment_containing_end_header_does_not_shift_the_data(tmp_path, where, line):
    """The header ends at the first line that is only ``end_header``: a comment holding the words once ended it
    early (no elements) or, placed after the properties, silently shifted every value by 11 bytes."""
    ply = random_ply(N=20, degree=1)
    SP.write_ply(tmp_path / "plain.ply", ply)
    data = _with_header_lines((tmp_path / "plain.ply").read_bytes(), **{where: [line]})
    (tmp_path / "commented.ply").write_bytes(data)
    back = SP.read_ply(tmp_path / "commented.ply")
    assert_raw_equal(ply, back)
    g, want = SP.load(tmp_path / "commented.ply"), SP.decode(ply)
    assert np.array_equal(g.means, want.means) and np.array_equal(g.sh, want.sh)
    assert np.array_equal(g.scales, want.scales) and np.array_equal(g.quats, want.quats)


def test_comment_written_by_write_ply_is_one_safe_line(tmp_path):
    ply = random_ply(N=5, extras=False)
    SP.write_ply(tmp_path / "c.ply", ply, comment="from end_header.glb\nelement vertex 99\r\ncafé")
    head = (tmp_path / "c.ply").read_bytes().split(b"\nend_header\n")[0].decode("ascii")
    assert "comment from end_header.glb?element vertex 99??caf?" in head.splitlines()
    assert_raw_equal(ply, SP.read_ply(tmp_path / "c.ply"))


def test_crlf_header_and_spaces_around_end_header(tmp_path):
    ply = random_ply(N=7, degree=0)
    SP.write_ply(tmp_path / "lf.ply", ply)
    head, body = (tmp_path / "lf.ply").read_bytes().split(b"end_header\n", 1)
    (tmp_path / "crlf.ply").write_bytes(head.replace(b"\n", b"\r\n") + b"end_header\r\n" + body)
    assert_raw_equal(ply, SP.read_ply(tmp_path / "crlf.ply"))
    (tmp_path / "spaces.ply").write_bytes(head + b"end_header  \n" + body)
    assert_raw_equal(ply, SP.read_ply(tmp_path / "spaces.ply"))


def test_header_problems_are_clean_errors(tmp_path):
    ply = random_ply(N=4, degree=0, extras=False)
    SP.write_ply(tmp_path / "ok.ply", ply)
    data = (tmp_path / "ok.ply").read_bytes()
    head, body = data.split(b"end_header\n", 1)

    def err(name, raw, match):
        (tmp_path / name).write_bytes(raw)
        with pytest.raises(SP.SplatsError, match=match) as e:
            SP.read(tmp_path / name)
        assert isinstance(e.value, SP.files.InputError) and name in str(e.value)
        return e.value

    err("glued.ply", head + b"end_header", "ends without a newline after 'end_header'")
    err("noend.ply", head, "no 'end_header' line: the file is truncated")
    err("long.ply", head + b"comment " + b"x" * SP.MAX_HEADER + b"\nend_header\n", "no 'end_header' line in the first")
    err("lines.ply", head + b"\n" * (SP.MAX_HEADER_LINES + 5) + b"end_header\n" + body, "more than 4096 lines")
    e = err("utf8.ply", head.replace(b"property float opacity", b"property float opacit\xc3\xa9") + b"end_header\n"
            + body, r"header line \d+: is not ASCII text")
    assert e.field.startswith("header line ") and not e.message.startswith("header line")
    e = err("element.ply", head.replace(b"element vertex 4", b"element vertex -4") + b"end_header\n" + body,
            r"header line 3: malformed element line")
    assert e.field == "header line 3"
    err("list.ply", head.replace(b"element vertex 4", b"element junk 1\nproperty list uchar\nelement vertex 4")
        + b"end_header\n" + body, "malformed list property")
    err("magic.ply", b"plyx" + data[3:], "its first line is not 'ply'")
    e = err("missing.ply", head.replace(b"property float rot_3\n", b"") + b"end_header\n" + body,
            r"missing required properties \['rot_3'\]")
    assert e.field == "rot_3"
    comment_utf8 = head.replace(b"format", b"comment caf\xc3\xa9 \xff\nformat") + b"end_header\n" + body
    (tmp_path / "comment.ply").write_bytes(comment_utf8)  # free text: any bytes, never parsed
    assert_raw_equal(ply, SP.read(tmp_path / "comment.ply"))


@pytest.mark.parametrize("count", ["999999999999999", "2147483648", "5"])
def test_element_counts_beyond_the_file_are_refused_before_allocation(tmp_path, count):
    SP.write_ply(tmp_path / "ok.ply", random_ply(N=4, degree=0, extras=False))
    data = (tmp_path / "ok.ply").read_bytes()
    cases = {"vertex.ply": data.replace(b"element vertex 4", b"element vertex " + count.encode()),
             "before.ply": data.replace(b"element vertex 4", b"element junk " + count.encode()
                                        + b"\nproperty double a\nproperty double b\nelement vertex 4")}
    for name, raw in cases.items():
        (tmp_path / name).write_bytes(raw)
        t = time.perf_counter()
        with pytest.raises(SP.SplatsError, match=r"truncated: the header promises \d+ Gaussians .* but the file has "
                                                 r"\d+ bytes") as e:
            SP.read(tmp_path / name)
        assert time.perf_counter() - t < 0.5 and e.value.field == "vertex"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name", ["pipe.ply", "pipe.splat", "pipe.compressed.ply"])
def test_fifo_and_directory_are_refused_at_once(tmp_path, name):
    """A FIFO given as an asset once blocked the reader for minutes (ignoring SIGTERM); now it is refused."""
    os.mkfifo(tmp_path / name)
    t = time.perf_counter()
    for fn in (SP.read, SP.load, SP.read_ply, SP.read_splat, SP.read_ply_header):
        with pytest.raises(SP.SplatsError, match=rf"{re.escape(name)}: is a FIFO \(named pipe\), not a regular file"):
            fn(tmp_path / name)
    assert not SP.is_mesh_ply(tmp_path / name)
    assert time.perf_counter() - t < 1.0
    (tmp_path / "folder.ply").mkdir()
    with pytest.raises(SP.SplatsError, match="folder.ply: is a directory") as e:
        SP.read(tmp_path / "folder.ply")
    assert e.value.field == "(file)"


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
    write_compressed(tmp_path / "compressed.ply", random_gaussians(300, 1, seed=7))  # 2 chunks, SH element
    sources.append((tmp_path / "compressed.ply").read_bytes())
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


# -- SuperSplat compressed PLY -------------------------------------------------------------------------------------

COMPRESSED = "compressed/olgelta_longheadpiece_scene.compressed.ply"


def random_gaussians(N, degree, seed):
    """Raw INRIA values, quaternions unit; some SH values beyond the compressed format's ±4 range."""
    rng = np.random.default_rng(seed)
    q = rng.normal(0, 1, (N, 4))
    K1 = SP.num_sh_coefficients(degree) - 1
    return SP.GaussianPly(
        xyz=rng.normal(0, 2, (N, 3)).astype(np.float32), f_dc=rng.normal(0, 1, (N, 3)).astype(np.float32),
        f_rest=rng.normal(0, 2, (N, 3, K1)).astype(np.float32), opacity=rng.normal(0, 3, N).astype(np.float32),
        scale=rng.normal(-4, 1, (N, 3)).astype(np.float32),
        rot=(q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32))


def write_compressed(path, ply, chunk_colors=True):
    return F.write_compressed_ply(path, ply.xyz, ply.scale, ply.rot, ply.f_dc, ply.opacity, ply.f_rest,
                                  chunk_colors=chunk_colors)


def same_rotation_error(a, b):
    """Largest distance between unit quaternions a and b (N, 4) taken up to sign (q and -q are one rotation)."""
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return np.minimum(np.abs(a - b).max(1), np.abs(a + b).max(1)).max()


@pytest.mark.parametrize("degree", [0, 3])
@pytest.mark.parametrize("chunk_colors", [True, False])
def test_compressed_decode_inverts_an_independent_encoder(tmp_path, degree, chunk_colors):
    """decode(encode(x)) = x within half a quantisation step, for 3 chunks (the last one partial)."""
    src = random_gaussians(700, degree, seed=degree + 10 * chunk_colors)
    p = tmp_path / "x.compressed.ply"
    table = write_compressed(p, src, chunk_colors).astype(np.float64)
    ply = SP.read(p)
    assert ply.format == "supersplat_compressed" and len(ply) == 700 and ply.sh_degree == degree
    assert SP.read_ply(p).format == "supersplat_compressed"  # read_ply dispatches too
    ci = np.arange(700) // 256
    for i, bits in enumerate((11, 10, 11)):
        step = (table[ci, 3 + i] - table[ci, i]) / (2 ** bits - 1)
        assert np.all(np.abs(ply.xyz[:, i] - src.xyz[:, i]) <= step / 2 + 1e-6), i
        sstep = (table[ci, 9 + i] - table[ci, 6 + i]) / (2 ** bits - 1)
        assert np.all(np.abs(ply.scale[:, i] - src.scale[:, i]) <= sstep / 2 + 1e-6), i
    colour = 0.5 + SP.SH_C0 * src.f_dc.astype(np.float64)
    got = 0.5 + SP.SH_C0 * ply.f_dc.astype(np.float64)
    if chunk_colors:
        cstep = (table[ci, 15:18] - table[ci, 12:15]) / 255
        assert np.all(np.abs(got - colour) <= cstep / 2 + 1e-6)
    else:  # colours are stored as they are, clipped to [0, 1]
        assert np.all(np.abs(got - np.clip(colour, 0, 1)) <= 0.5 / 255 + 1e-6)
    alpha = 1 / (1 + np.exp(-src.opacity.astype(np.float64)))
    assert np.all(np.abs(1 / (1 + np.exp(-ply.opacity.astype(np.float64))) - alpha) <= 0.5 / 255 + 1e-6)
    assert np.all(np.isfinite(ply.opacity))
    assert same_rotation_error(ply.rot.astype(np.float64), src.rot.astype(np.float64)) < 2e-3
    assert np.abs(np.linalg.norm(ply.rot, axis=1) - 1).max() < 1e-5
    if degree:
        v, d = src.f_rest.astype(np.float64), ply.f_rest.astype(np.float64)
        inner = np.abs(v) < 4 - 1 / 32
        assert np.all(np.abs(d - v)[inner] <= 1 / 64 + 1e-6)  # the middle of a 1/32 bucket
        assert np.all(d[v >= 4 - 1 / 32] == 4.0) and np.all(d[v <= -4 + 1 / 32] == -4.0)
    g = SP.load(p)
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
    src = random_gaussians(len(qs), 0, seed=4)
    src.rot = qs.astype(np.float32)
    write_compressed(tmp_path / "q.ply", src)
    got = SP.read(tmp_path / "q.ply").rot.astype(np.float64)
    for (largest, sign), q, d in zip(cases, qs, got):
        assert d[largest] > 0
        assert np.abs(d - sign * q).max() < 2e-3, (largest, sign)


def test_compressed_rotation_word_by_hand():
    """A 120° turn about +y, q = (w, x, y, z) = (0.5, 0, 0.866, 0): y (index 2) is largest; w, x, z are stored in
    that order as floor((q·√2/2 + 0.5)·1023 + 0.5) = 873, 512, 512."""
    word = (2 << 30) | (873 << 20) | (512 << 10) | 512
    q = SP.decode_packed_rotation(np.array([word], np.uint32))[0]
    w, x, z = (np.array([873, 512, 512]) / 1023 - 0.5) * np.sqrt(2)
    assert np.allclose(q, [w, x, np.sqrt(1 - w * w - x * x - z * z), z], atol=1e-12)
    assert np.allclose(q, [0.5, 0, np.sqrt(0.75), 0], atol=1.5e-3)
    R = C.quaternion_to_rotation(q[None] / np.linalg.norm(q))[0]
    assert np.allclose(R @ [1, 0, 0], [np.cos(np.radians(120)), 0, -np.sin(np.radians(120))], atol=3e-3)


def test_compressed_sh_bytes(tmp_path):
    """SH byte k decodes to the middle of its bucket, ((k + 0.5)/256 - 0.5)·8, with 0 and 255 at -4 and +4."""
    src = random_gaussians(5, 1, seed=5)
    write_compressed(tmp_path / "sh.ply", src)
    raw = (tmp_path / "sh.ply").read_bytes()
    sh_bytes = np.array([[0, 1, 128, 254, 255, 127, 64, 192, 200]] * 5, np.uint8)
    (tmp_path / "sh.ply").write_bytes(raw[: len(raw) - sh_bytes.size] + sh_bytes.tobytes())
    got = SP.read(tmp_path / "sh.ply").f_rest.reshape(5, 9)[0]
    mid = ((np.array([0, 1, 128, 254, 255, 127, 64, 192, 200]) + 0.5) / 256 - 0.5) * 8
    mid[0], mid[4] = -4.0, 4.0
    assert np.allclose(got, mid, atol=1e-6)
    assert np.isclose(got[1], -3.953125) and np.isclose(got[2], 0.015625)


def test_compressed_errors_name_the_file_and_problem(tmp_path):
    src = random_gaussians(300, 1, seed=6)
    p = tmp_path / "good.ply"
    write_compressed(p, src)
    data = p.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[:-100])
    with pytest.raises(SP.SplatsError, match=r"cut\.ply.*truncated.*300 SH rows"):
        SP.read(tmp_path / "cut.ply")
    (tmp_path / "cut2.ply").write_bytes(data[: len(data) // 2])
    with pytest.raises(SP.SplatsError, match=r"cut2\.ply.*truncated.*300 Gaussians"):
        SP.read(tmp_path / "cut2.ply")
    (tmp_path / "chunks.ply").write_bytes(data.replace(b"element chunk 2", b"element chunk 3"))
    with pytest.raises(SP.SplatsError, match=r"chunks\.ply.*300 Gaussians need 2 chunks.*has 3"):
        SP.read(tmp_path / "chunks.ply")
    (tmp_path / "nochunk.ply").write_bytes(data.replace(b"element chunk", b"element chunx"))
    with pytest.raises(SP.SplatsError, match="no 'chunk' element"):
        SP.read(tmp_path / "nochunk.ply")
    (tmp_path / "packed.ply").write_bytes(data.replace(b"uint packed_scale", b"uint packed_scalf"))
    with pytest.raises(SP.SplatsError, match=r"missing \['packed_scale'\]"):
        SP.read(tmp_path / "packed.ply")
    (tmp_path / "shtype.ply").write_bytes(data.replace(b"uchar f_rest_3", b"char f_rest_3"))
    with pytest.raises(SP.SplatsError, match="sh property 'f_rest_3' is char.*expected uchar"):
        SP.read(tmp_path / "shtype.ply")


def _chunk_table(path):
    """The chunk element of a compressed PLY, parsed here independently of core.splats."""
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
        t = time.perf_counter()
        ply = SP.read(path)
        times.append(time.perf_counter() - t)
    print(f"compressed read + unpack: best {min(times) * 1e3:.0f} ms of {[round(x * 1e3) for x in times]}")
    assert min(times) < 1.0
    N = 220_315
    assert len(ply) == N and ply.format == "supersplat_compressed" and ply.sh_degree == 0
    for a in (ply.xyz, ply.f_dc, ply.opacity, ply.scale, ply.rot):
        assert np.all(np.isfinite(a))
    assert np.abs(np.linalg.norm(ply.rot.astype(np.float64), axis=1) - 1).max() < 1e-5
    g = SP.decode(ply)
    assert len(g) == N and g.dropped == {}
    assert g.opacities.min() >= 0 and g.opacities.max() <= 1

    table = _chunk_table(path)
    assert len(table["min_x"]) == 861
    ci = np.arange(N) // 256
    colour = 0.5 + SP.SH_C0 * ply.f_dc.astype(np.float64)
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
    with pytest.raises(SP.SplatsError, match=r"cut\.compressed\.ply: truncated.*220315 Gaussians"):
        SP.load(tmp_path / "cut.compressed.ply")


# -- antimatter15 .splat -------------------------------------------------------------------------------------------

def test_splat_byte_conventions(tmp_path):
    rec = np.zeros(3, SP.SPLAT_RECORD)
    rec["xyz"] = [[1, 2, 3], [-1, 0, 0.5], [0, 0, 0]]
    rec["scale"] = [[0.1, 0.2, 0.4], [1, 1, 1], [0.01, 0.02, 0.03]]
    rec["rgba"] = [[255, 0, 128, 255], [10, 20, 30, 0], [128, 128, 128, 128]]
    rec["rot"] = [[192, 128, 128, 192], [255, 128, 128, 128], [128, 128, 128, 128]]
    (tmp_path / "t.splat").write_bytes(rec.tobytes())
    ply = SP.read(tmp_path / "t.splat")
    assert ply.format == "splat" and len(ply) == 3 and ply.sh_degree == 0
    assert np.array_equal(ply.xyz, rec["xyz"])
    assert np.allclose(ply.scale, np.log(rec["scale"].astype(np.float32)), atol=1e-6)
    assert np.allclose(ply.f_dc[0], [(1 - 0.5) / SP.SH_C0, -0.5 / SP.SH_C0, (128 / 255 - 0.5) / SP.SH_C0])
    assert np.allclose(ply.rot[0], [0.5, 0, 0, 0.5]) and np.allclose(ply.rot[1], [127 / 128, 0, 0, 0])
    a = 1 - 1e-6
    assert np.isclose(ply.opacity[0], np.log(a / (1 - a)), rtol=1e-5)  # 255 stays finite
    assert np.isclose(ply.opacity[1], -np.log(a / (1 - a)), rtol=1e-5)  # and so does 0
    g = SP.load(tmp_path / "t.splat")
    assert g.dropped == {"zero_quaternion": 1} and len(g) == 2  # bytes 128,128,128,128 are a zero quaternion
    assert np.allclose(g.quats[0], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-6)
    assert np.allclose(g.base_colors()[0], [1.0, 0.0, 128 / 255], atol=1e-6)


def test_splat_write_read_round_trip(tmp_path):
    g = SP.decode(random_gaussians(400, 0, seed=8))
    SP.write_splat(tmp_path / "g.splat", g)
    assert (tmp_path / "g.splat").stat().st_size == 32 * 400
    back = SP.load(tmp_path / "g.splat")
    assert len(back) == 400 and back.dropped == {}
    assert np.array_equal(back.means, g.means)
    assert np.allclose(back.scales, g.scales, rtol=1e-6)
    assert np.all(np.abs(back.opacities - g.opacities) <= 0.5 / 255 + 1e-6)
    expected = np.clip(g.base_colors(), 0, 1)
    assert np.all(np.abs(back.base_colors() - expected) <= 0.5 / 255 + 1e-6)
    assert same_rotation_error(back.quats.astype(np.float64), g.quats.astype(np.float64)) < 0.02
    # a raw GaussianPly is accepted too (decoded first)
    SP.write_splat(tmp_path / "raw.splat", random_gaussians(400, 0, seed=8))
    assert (tmp_path / "raw.splat").read_bytes() == (tmp_path / "g.splat").read_bytes()


def test_splat_size_must_be_a_multiple_of_32(tmp_path):
    SP.write_splat(tmp_path / "ok.splat", SP.decode(random_gaussians(3, 0, seed=9)))
    data = (tmp_path / "ok.splat").read_bytes()
    (tmp_path / "bad.splat").write_bytes(data[:-5])
    with pytest.raises(SP.SplatsError, match=r"bad\.splat.*91 bytes, not a multiple of 32"):
        SP.read(tmp_path / "bad.splat")
    (tmp_path / "empty.splat").write_bytes(b"")
    with pytest.raises(SP.SplatsError, match=r"empty\.splat.*empty"):
        SP.load(tmp_path / "empty.splat")


# -- property types: half floats and integers ----------------------------------------------------------------------

@pytest.mark.parametrize("order", ["<", ">"])
def test_half_float_ply(tmp_path, order):
    """Every Gaussian property in ushort slots: the bits are IEEE half floats in the file's byte order."""
    src = random_ply(N=60, degree=1, extras=False)
    half = {k: getattr(src, k).astype(np.float16) for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot")}
    src16 = SP.GaussianPly(**half)
    cols = F.inria_columns(src16, "ushort", cast=lambda v: v.view(np.uint16))
    cols.insert(3, ("label", "ushort", np.arange(60, dtype=np.uint16)))  # an extra keeps its own type
    F.write_typed_ply(tmp_path / "h.ply", cols, byte_order=order)
    ply = SP.read(tmp_path / "h.ply")
    assert ply.format == "inria_half"
    for k in ("xyz", "f_dc", "f_rest", "opacity", "scale", "rot"):
        assert np.array_equal(getattr(ply, k), half[k].astype(np.float32)), k
    assert ply.extra["label"].dtype == np.uint16 and np.array_equal(ply.extra["label"], np.arange(60))
    g = SP.load(tmp_path / "h.ply")
    assert len(g) == 60 and np.allclose(g.scales, np.exp(half["scale"].astype(np.float64)), rtol=1e-6)


def test_integer_gaussian_properties_are_refused_by_name(tmp_path):
    src = random_ply(N=20, degree=0, extras=False)
    cols = F.inria_columns(src, "float")
    mixed = [(n, "ushort", np.float16(v).view(np.uint16)) if n.startswith("scale_") else (n, t, v)
             for n, t, v in cols]
    F.write_typed_ply(tmp_path / "mixed.ply", mixed)
    with pytest.raises(SP.SplatsError, match=r"mixed\.ply: property 'scale_0' \(and 2 more\) is stored as ushort "
                                             r"\(uint16\).*re-export the file as float32") as e:
        SP.load(tmp_path / "mixed.ply")
    assert "scale_overflow" not in str(e.value)
    as_bytes = [(n, "uchar", np.zeros(20, np.uint8)) for n, _, _ in cols]
    F.write_typed_ply(tmp_path / "bytes.ply", as_bytes)
    with pytest.raises(SP.SplatsError, match=r"property 'x' \(and 13 more\) is stored as uchar \(uint8\).*float32"):
        SP.read(tmp_path / "bytes.ply")
    ints = [(n, "int", np.ones(20, np.int32)) if n == "opacity" else (n, t, v) for n, t, v in cols]
    F.write_typed_ply(tmp_path / "int.ply", ints)
    with pytest.raises(SP.SplatsError, match=r"property 'opacity' is stored as int \(int32\)"):
        SP.read(tmp_path / "int.ply")
    doubles = [(n, "double", v) for n, t, v in cols]
    F.write_typed_ply(tmp_path / "double.ply", doubles)
    ply = SP.read(tmp_path / "double.ply")
    assert ply.format == "inria" and np.array_equal(ply.xyz, src.xyz)


# -- one entry point -----------------------------------------------------------------------------------------------

def test_read_dispatches_by_content(tmp_path):
    src = random_ply(N=30, degree=2)
    SP.write_ply(tmp_path / "scene.bin", src)  # a PLY under another name is still a PLY
    assert SP.read(tmp_path / "scene.bin").format == "inria"
    assert_raw_equal(SP.read(tmp_path / "scene.bin"), src)
    write_compressed(tmp_path / "c.ply", random_gaussians(30, 0, seed=1))
    assert SP.read(tmp_path / "c.ply").format == "supersplat_compressed"
    SP.write_splat(tmp_path / "s.splat", SP.decode(random_gaussians(30, 0, seed=1)))
    assert SP.read(tmp_path / "s.splat").format == "splat"
    assert set(SP.FORMAT_NAMES) == {"inria", "inria_half", "supersplat_compressed", "splat"}
    with pytest.raises(SP.SplatsError, match="not found"):
        SP.read(tmp_path / "nope.splat")


def test_mesh_ply_is_told_to_import_as_a_mesh(tmp_path):
    xyz = np.random.default_rng(0).normal(0, 1, (4, 3))
    F.write_typed_ply(tmp_path / "mesh.ply", [(k, "double", xyz[:, i]) for i, k in enumerate("xyz")],
                      faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.raises(SP.SplatsError, match=r"mesh\.ply: looks like a mesh without Gaussian properties.*2 faces"
                                             r".*import it as a mesh asset \(\.glb/\.obj/\.ply mesh\)"):
        SP.read(tmp_path / "mesh.ply")
    assert SP.is_mesh_ply(tmp_path / "mesh.ply")
    SP.write_ply(tmp_path / "g.ply", random_ply(N=5))
    assert not SP.is_mesh_ply(tmp_path / "g.ply") and not SP.is_mesh_ply(tmp_path / "nope.ply")
    F.write_typed_ply(tmp_path / "points.ply", [(k, "float", xyz[:, i]) for i, k in enumerate("xyz")]
                      + [(c, "uchar", np.zeros(4, np.uint8)) for c in ("red", "green", "blue")])
    with pytest.raises(SP.SplatsError, match="looks like a mesh without Gaussian properties"):
        SP.read(tmp_path / "points.ply")
    assert not SP.is_mesh_ply(tmp_path / "points.ply")  # no faces: nothing to convert
    ascii_mesh = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                  "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    (tmp_path / "ascii_mesh.ply").write_text(ascii_mesh)
    assert SP.is_mesh_ply(tmp_path / "ascii_mesh.ply")
    with pytest.raises(SP.SplatsError, match=r"ascii_mesh\.ply: looks like a mesh.*1 faces"):
        SP.read(tmp_path / "ascii_mesh.ply")


def test_real_trellis_mesh_ply_and_glb():
    mesh = realdata("trellis/trellis_assets_T_mesh.ply")
    with pytest.raises(SP.SplatsError, match=r"trellis_assets_T_mesh\.ply: looks like a mesh .*53789 vertices "
                                             r"\(x y z\) and 61402 faces.*import it as a mesh asset"):
        SP.load(mesh)
    assert SP.is_mesh_ply(mesh)
    glb = realdata("trellis/uanu2002_trellis_sample.glb")
    with pytest.raises(SP.SplatsError, match=r"uanu2002_trellis_sample\.glb: a mesh \(\.glb\).*mesh-asset.*accepted are"):
        SP.read(glb)


def test_other_files_name_the_accepted_formats(tmp_path):
    (tmp_path / "model.glb").write_bytes(b"glTF\x02\x00\x00\x00" + bytes(100))
    with pytest.raises(SP.SplatsError, match=r"model\.glb: a mesh \(\.glb\).*\.splat"):
        SP.read(tmp_path / "model.glb")
    (tmp_path / "car.fbx").write_bytes(b"Kaydara FBX Binary  \x00" + bytes(100))  # not read at all: say so
    with pytest.raises(SP.SplatsError, match=r"car\.fbx: \.fbx files are not read: export the car as GLB"):
        SP.read(tmp_path / "car.fbx")
    (tmp_path / "scene.spz").write_bytes(bytes(100))
    with pytest.raises(SP.SplatsError, match=r"\.spz Gaussian files are not supported.*splat-transform"):
        SP.read(tmp_path / "scene.spz")
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)))
    with pytest.raises(SP.SplatsError, match=r"noise\.bin: not a PLY file.*accepted are .*SuperSplat compressed"):
        SP.load(tmp_path / "noise.bin")
    with pytest.raises(SP.SplatsError, match="not a PLY file"):
        SP.read_ply(tmp_path / "noise.bin")


def test_real_inria_files_read_as_inria():
    for rel, n, degree in (("3dgs/loadersgl_train-1000.ply", 1000, 3), ("3dgs/gshairlod_donut_fused.ply", 45624, 0),
                           ("3dgs/supersplat_fruit_drops_minimal.ply", 4721, 3)):
        ply = SP.read(realdata(rel))
        assert (len(ply), ply.sh_degree, ply.format) == (n, degree, "inria"), rel
        assert SP.detect_axes(ply)[0] == "NONE"


# -- TRELLIS / Amodal3R detection ----------------------------------------------------------------------------------

def test_trellis_bound_from_the_decoder():
    # 64^3 voxels, Gaussians up to 0.75 voxel (0.5 · voxel_size 1.5) from their voxel centre; checked against
    # microsoft/TRELLIS trellis/models/structured_latent_vae/decoder_gs.py
    assert abs(SP.TRELLIS_MEAN_BOUND - (0.5 + 0.75 / 64)) < 1e-4
    assert SP.TRELLIS_MEAN_BOUND > 0.5 - 0.5 / 64 + 0.75 / 64  # the farthest a real TRELLIS mean can be


def test_detect_axes_trellis_car_touching_the_cube(tmp_path):
    """A car filling the cube, some means 0.504 from the origin (the decoder's voxel offset): TRELLIS."""
    path = tmp_path / "car.ply"
    shapes.save_as_amodal3r(path, shapes.procedural_car_gaussians(count=3000, seed=1))
    ply = SP.read(path)
    ply.xyz *= np.float32(0.504 / np.abs(ply.xyz).max())
    SP.write_ply(path, ply)
    ply = SP.read(path)
    assert 0.5 < np.abs(ply.xyz).max() <= 0.5041
    axes, reason = SP.detect_axes(ply, SP.valid_rows(ply)[0])
    assert axes == "TRELLIS", reason
    assert reason == ("TRELLIS/Amodal3R layout (17 properties, zero normals, SH 0) and all means within ±0.5117 "
                      "(the decoder's unit cube)")
    # the same object scaled past the decoder's reach is not TRELLIS
    ply.xyz *= np.float32(0.73 / 0.504)
    assert SP.detect_axes(ply) == ("NONE", "not TRELLIS: means reach 0.73, outside the unit cube (TRELLIS stays "
                                           "within ±0.5117)")
    zup, _ = trellis_like_file(tmp_path / "t.ply")
    assert SP.detect_axes(SP.read(tmp_path / "t.ply"))[0] == "TRELLIS"


def test_detect_axes_not_trellis(tmp_path):
    SP.write_ply(tmp_path / "scene.ply", random_ply(N=50, degree=3))
    assert SP.detect_axes(SP.read(tmp_path / "scene.ply")) == ("NONE", "not TRELLIS: has f_rest (SH 3)")
    small = random_ply(N=50, degree=0, extras=False)
    small.xyz *= np.float32(0.1)
    SP.write_ply(tmp_path / "sh0.ply", small)
    axes, reason = SP.detect_axes(SP.read(tmp_path / "sh0.ply"))
    assert axes == "NONE" and reason.startswith("not TRELLIS: no normals")
    labelled = random_ply(N=50, degree=0)  # normals plus a 'label' property
    labelled.xyz *= np.float32(0.1)
    assert SP.detect_axes(labelled) == ("NONE", "not TRELLIS: extra properties ['label']")
    trellis_like_file(tmp_path / "t.ply")
    ply = SP.read(tmp_path / "t.ply")
    ply.extra["nx"][3] = 1.0
    assert SP.detect_axes(ply) == ("NONE", "not TRELLIS: normals are not all zero")
    # same properties, another order
    cols = F.inria_columns(SP.read(tmp_path / "t.ply"))
    cols = cols[:3] + [(n, "float", np.zeros(40, np.float32)) for n in ("nx", "ny", "nz")][::-1] + cols[3:]
    F.write_typed_ply(tmp_path / "order.ply", cols)
    assert SP.detect_axes(SP.read(tmp_path / "order.ply"))[1] == ("not TRELLIS: the properties are not in "
                                                                  "TRELLIS's save_ply order")
    write_compressed(tmp_path / "c.ply", random_gaussians(30, 0, seed=2))
    assert SP.detect_axes(SP.read(tmp_path / "c.ply"))[1] == "not TRELLIS: its layout is SuperSplat compressed PLY"
