"""core.splats.spz: Niantic SPZ written by the real writer (splat-transform, which packs with Niantic's own code,
versions 3 and 4) and version 2 written here from the format's description, read back within SPZ's quantisation of
our read of the source PLY; content detection (an SPZ under another name); damaged files refused by name."""

import gzip

import numpy as np
import pytest

from tests.core.splats import splat_fixtures as F
import splat_transform
from tests_support import realdata
from scpainter_blender.core.splats import gaussians as splats, reader as splats_io, spz

REAL = ("3dgs/loadersgl_train-1000.ply", "3dgs/supersplat_fruit_drops_minimal.ply", "3dgs/gshairlod_donut_fused.ply")

# The bounds, each the format's quantisation step (Niantic's packer, src/cc/load-spz.cc) plus float32 rounding:
#: positions: 24-bit fixed point with 12 fractional bits (splat-transform's files): half a step, 2^-13.
POSITION_BOUND = 2.0 ** -13 + 1e-6
#: log σ: one byte per (log σ + 10) · 16: half a step 1/32, of the value clamped to the byte's range [-10, 5.9375].
LOG_SCALE_BOUND = 1.0 / 32 + 1e-6
LOG_SCALE_RANGE = (-10.0, 15.9375)
#: opacity after the sigmoid: one byte, half a step 1/510 (compared after the sigmoid: a byte's logit is unbounded).
OPACITY_BOUND = 0.5 / 255 + 1e-6
#: f_dc: one byte of f_dc · 0.15 + 0.5: half a step 1/(2 · 255 · 0.15), within the byte's range.
DC_BOUND = 0.5 / 255 / spz.COLOR_SCALE + 1e-6
#: SH degree >= 1: a byte of v · 128 + 128 rounded, then kept to 4 bits (splat-transform's shRestBits; 5 for degree
#: 1): half a 16-unit bucket plus half a unit, over 128 — of the value clamped to the byte's range [-1, 127/128].
SH_BOUND = (8 + 0.5) / 128 + 1e-6
#: quaternions (unit, up to sign), per component: v3/v4 store the three smallest in 9 bits of ±√½ (half a step
#: √½/511/2) and the largest is derived from them, which can add up to about three such errors.
QUAT_BOUND = 4 * np.sqrt(0.5) / 511 + 1e-6
#: v2 stores x y z (of the quaternion with w >= 0) as bytes of ±1: half a step 1/255. Its w is derived as
#: √(1 - x² - y² - z²), which near w = 0 magnifies those errors without bound: v2's own weakness, why v3 came; so w
#: is checked against that formula, not against the source.
QUAT_XYZ_BOUND_V2 = 0.5 / 127.5 + 1e-6


def assert_close_to_source(got, src, quat_bound=QUAT_BOUND):
    """``got`` (read from an SPZ) against ``src`` (the PLY's raw values) within the bounds above."""
    assert len(got) == len(src) and got.sh_degree == src.sh_degree and got.format == "spz"
    assert np.abs(got.xyz - src.xyz).max() <= POSITION_BOUND
    assert np.abs(got.scale - np.clip(src.scale, *LOG_SCALE_RANGE)).max() <= LOG_SCALE_BOUND
    o = lambda p: splats.opacities_from_logits(p.opacity)  # noqa: E731
    assert np.abs(o(got) - o(src)).max() <= OPACITY_BOUND
    lo, hi = (0 - 0.5) / spz.COLOR_SCALE, (1 - 0.5) / spz.COLOR_SCALE
    assert np.abs(got.f_dc - np.clip(src.f_dc, lo, hi)).max() <= DC_BOUND
    if src.sh_degree:
        assert np.abs(got.f_rest - np.clip(src.f_rest, -1.0, 127 / 128)).max() <= SH_BOUND
    if quat_bound is not None:
        qg, qs = (splats.unit_quaternions(p.rot) for p in (got, src))
        qg *= np.where((qg * qs).sum(1) < 0, -1.0, 1.0)[:, None]
        assert np.abs(qg - qs).max() <= quat_bound


@pytest.mark.parametrize("version", [3, 4])
@pytest.mark.parametrize("rel", REAL + (F.GENERATED,))
def test_splat_transform_spz_reads_back_within_quantisation(tmp_path, rel, version):
    src_path = F.source_ply(rel, tmp_path)
    out = splat_transform.convert(src_path, tmp_path / "scene.spz", "--spz-version", version)
    with open(out, "rb") as f:
        assert f.read(2) == (b"\x1f\x8b" if version == 3 else b"NG")  # gzip (v3) or the plain v4 header
    assert splats_io.detect(out) == "spz"
    assert_close_to_source(splats_io.read(out), splats_io.read(src_path))


def test_spz_under_another_name_is_read_as_spz(tmp_path):
    src_path = realdata(REAL[0])
    out = splat_transform.convert(src_path, tmp_path / "scene.spz", "--spz-version", 3)
    renamed = tmp_path / "scene.splat"  # a headered file named .splat is read as what it is
    renamed.write_bytes(open(out, "rb").read())
    assert splats_io.read(renamed).format == "spz"
    np.testing.assert_array_equal(splats_io.read(renamed).xyz, splats_io.read(out).xyz)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_version_2_written_from_the_description(tmp_path, degree):
    src = F.random_ply(N=500, degree=degree, seed=degree)
    src.xyz = np.clip(src.xyz, -100, 100)
    F.write_spz(tmp_path / "v2.spz", src)
    got = splats_io.read(tmp_path / "v2.spz")
    # v2's SH bytes are not bucketed: half a step of 1/128
    src.f_rest = np.clip(src.f_rest, -1.0, 127 / 128)
    assert_close_to_source(got, src, quat_bound=None)
    q = splats.unit_quaternions(src.rot)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    assert np.abs(got.rot[:, 1:] - q[:, 1:]).max() <= QUAT_XYZ_BOUND_V2
    w = np.sqrt(np.maximum(0.0, 1.0 - (got.rot[:, 1:].astype(np.float64) ** 2).sum(1)))
    np.testing.assert_allclose(got.rot[:, 0], w, atol=1e-5)  # float32 x y z, magnified near w = 0
    if degree:
        assert np.abs(got.f_rest - src.f_rest).max() <= 0.5 / 128 + 1e-6


def test_version_3_written_from_the_description(tmp_path):
    """splat_fixtures.write_spz's version 3 (smallest-three rotations, what the fuzzer's SPZ cases start from)."""
    src = F.random_ply(N=400, degree=1, seed=7)
    src.xyz = np.clip(src.xyz, -100, 100)
    F.write_spz(tmp_path / "v3.spz", src, version=3)
    src.f_rest = np.clip(src.f_rest, -1.0, 127 / 128)
    got = splats_io.read(tmp_path / "v3.spz")
    assert_close_to_source(got, src)
    assert np.abs(got.f_rest - src.f_rest).max() <= 0.5 / 128 + 1e-6


def test_damaged_spz_files_are_refused_by_name(tmp_path):
    src = F.random_ply(N=50, degree=1, seed=4)
    F.write_spz(tmp_path / "ok.spz", src)
    data = gzip.decompress((tmp_path / "ok.spz").read_bytes())
    (tmp_path / "cut.spz").write_bytes(gzip.compress(data[:-100]))
    with pytest.raises(splats.SplatsError, match=r"cut\.spz: SPZ file truncated: 50 Gaussians of SH degree 1"):
        splats_io.read(tmp_path / "cut.spz")
    (tmp_path / "v9.spz").write_bytes(gzip.compress(data[:4] + b"\x09\x00\x00\x00" + data[8:]))
    with pytest.raises(splats.SplatsError, match=r"v9\.spz: SPZ version 9 is not read"):
        splats_io.read(tmp_path / "v9.spz")
    (tmp_path / "bad.spz").write_bytes((tmp_path / "ok.spz").read_bytes()[:40])
    with pytest.raises(splats.SplatsError, match=r"bad\.spz: "):
        splats_io.read(tmp_path / "bad.spz")


def test_spz_whose_stream_holds_more_than_its_header_says_is_refused(tmp_path):
    """Fuzz finding (tests/fuzz_splat_formats.py, issue 31): a count one short, an SH degree 0 over degree-1 data or
    bytes after the attributes were read misaligned and accepted; a stream cut in its trailer was accepted."""
    src = F.random_ply(N=30, degree=1, seed=5)
    body = F.spz_body(src, 3)
    for name, data in (("short.spz", F.spz_body(src, 3, count=29)), ("deg0.spz", F.spz_body(src, 3, degree=0)),
                       ("tail.spz", body + b"garbage")):
        (tmp_path / name).write_bytes(gzip.compress(data))
        with pytest.raises(splats.SplatsError, match=name.replace(".", r"\.") + ": SPZ header says .* but its gzip "
                                                     "stream holds more: the count or SH degree is wrong") as e:
            splats_io.read(tmp_path / name)
        assert e.value.field == "count"
    (tmp_path / "cut.spz").write_bytes(gzip.compress(body)[:-4])  # all attributes, the checksum cut
    with pytest.raises(splats.SplatsError, match=r"cut\.spz: its gzip stream ends before its end marker"):
        splats_io.read(tmp_path / "cut.spz")
    (tmp_path / "two.spz").write_bytes(gzip.compress(body) + gzip.compress(b"another member"))
    assert len(splats_io.read(tmp_path / "two.spz")) == 30  # a second gzip member is not SPZ's stream


def test_spz_claiming_a_billion_gaussians_is_refused_before_inflating(tmp_path):
    """A gzip bomb: 10^9 Gaussians claimed over 64 MiB of zeros in a 64 KiB file is refused without inflating it
    (deflate expands at most 1032:1); peak Python/numpy allocation measured with tracemalloc."""
    import tracemalloc
    import zlib

    z = zlib.compressobj(9, zlib.DEFLATED, 31)
    out = z.compress(F.spz_body(F.random_ply(N=1, degree=1), 3, count=10 ** 9)[:16])
    for _ in range(64):
        out += z.compress(bytes(1 << 20))
    (tmp_path / "bomb.spz").write_bytes(out + z.flush())
    tracemalloc.start()
    try:
        with pytest.raises(splats.SplatsError, match=r"1,000,000,000 Gaussians .* more than a gzip stream of "):
            splats_io.read(tmp_path / "bomb.spz")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 4 << 20, peak  # the file itself (~64 KiB) and the reader's head, not the claimed 29 GB
